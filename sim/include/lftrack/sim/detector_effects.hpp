#pragma once
// What a real flat-panel detector adds to a frame beyond photon noise, blur and quantisation
// (issue 21, "Detector"). Everything here is a property of one detector: a fixed pattern drawn
// once from `pattern_seed` as a function of the absolute pixel (row, col), so any window of the
// detector sees the same pattern in every frame.
//
// Typical values (the clinical preset's), for an amorphous-silicon panel with a CsI scintillator:
//   glare      5 % of the signal spread with sigma 3 mm: the low-frequency drop of a CsI panel's
//              MTF (the Lubberts effect; e.g. Samei and Flynn, Med. Phys. 29 (2002) 447).
//   lag        3 % of the previous frame read out again (first-frame lag of a-Si panels, 2-10 %:
//              Siewerdsen and Jaffray, Med. Phys. 26 (1999) 1624).
//   gain       0.5 % rms smooth and 0.3 % rms per pixel left after the flat field (the flat
//              field drifts with temperature and exposure history between calibrations).
//   defects    0.1 % of the pixels and 2 lines left uncorrected by the defect map (panels ship
//              with up to about 1 % defective pixels; the map catches most of them).
//   heel       3 % intensity change across the detector along the anode-cathode axis (the
//              columns, top to bottom) left by a flat field taken at another distance or kV.

#include <cstdint>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

// The detector's fixed pattern, evaluated per absolute pixel of a rows x cols detector.
class DetectorPattern {
 public:
  DetectorPattern(const sim_spec::DetectorEffectsSpec& spec, int detector_rows, int detector_cols);
  // Intensity of the beam at the pixel relative to the detector's centre (the heel effect).
  double heel(int row) const;
  // Residual gain of the pixel (smooth x pixel x line), about 1.
  double gain(int row, int col) const;
  // A stuck pixel's level as a fraction of the open-field signal in (0.05, 1.2], or a negative
  // value for a working pixel.
  double stuck_level(int row, int col) const;

 private:
  sim_spec::DetectorEffectsSpec spec_;
  int rows_, cols_;
  // The smooth gain: three plane waves over the detector.
  double wave_amplitude_ = 0;
  double wave_kx_[3] = {}, wave_ky_[3] = {}, wave_phase_[3] = {};
  // The defective lines: index (row if < rows, else column rows + c) and gain.
  int line_index_[8] = {};
  double line_gain_[8] = {};
  int lines_ = 0;
};

}  // namespace lftrack::sim
