#include "dicom_writer.hpp"

#include <gdcmAttribute.h>
#include <gdcmFile.h>
#include <gdcmFileMetaInformation.h>
#include <gdcmFragment.h>
#include <gdcmSequenceOfFragments.h>
#include <gdcmUIDGenerator.h>
#include <gdcmWriter.h>

#include <cstdio>

namespace lftrack::test {

std::int16_t pattern_value(int seed, int row, int col) {
  return static_cast<std::int16_t>(1000 + 37 * seed + 11 * row + 3 * col);
}

bool write_synthetic_slice(const std::filesystem::path& file, const SyntheticSlice& s) {
  gdcm::Writer writer;
  gdcm::File& f = writer.GetFile();
  gdcm::DataSet& ds = f.GetDataSet();
  gdcm::UIDGenerator uid;

  auto put_string = [&](uint16_t g, uint16_t e, gdcm::VR vr, const std::string& value) {
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(vr);
    std::string v = value;
    if (v.size() % 2) v += (vr == gdcm::VR::UI ? '\0' : ' ');
    de.SetByteValue(v.data(), static_cast<uint32_t>(v.size()));
    ds.Replace(de);
  };
  auto decimals = [](std::initializer_list<double> values) {
    std::string out;
    char buf[32];
    for (double v : values) {
      std::snprintf(buf, sizeof buf, "%.10g", v);
      if (!out.empty()) out += '\\';
      out += buf;
    }
    return out;
  };
  auto put_us = [&](uint16_t g, uint16_t e, uint16_t value) {
    gdcm::DataElement de(gdcm::Tag(g, e));
    de.SetVR(gdcm::VR::US);
    de.SetByteValue(reinterpret_cast<const char*>(&value), 2);
    ds.Replace(de);
  };

  put_string(0x0008, 0x0016, gdcm::VR::UI, "1.2.840.10008.5.1.4.1.1.2");  // CT Image Storage
  put_string(0x0008, 0x0018, gdcm::VR::UI, uid.Generate());
  put_string(0x0008, 0x0060, gdcm::VR::CS, s.modality);
  put_string(0x0020, 0x000D, gdcm::VR::UI, "1.2.826.0.1.3680043.2.1125.9");
  put_string(0x0020, 0x000E, gdcm::VR::UI, s.series_uid);
  if (!s.frame_of_reference_uid.empty()) put_string(0x0020, 0x0052, gdcm::VR::UI, s.frame_of_reference_uid);
  put_string(0x0020, 0x0032, gdcm::VR::DS,
             decimals({s.position_mm.x(), s.position_mm.y(), s.position_mm.z()}));
  put_string(0x0020, 0x0037, gdcm::VR::DS,
             decimals({s.row_cosine.x(), s.row_cosine.y(), s.row_cosine.z(), s.col_cosine.x(),
                       s.col_cosine.y(), s.col_cosine.z()}));
  put_string(0x0028, 0x0030, gdcm::VR::DS, decimals({s.pixel_spacing_mm.x(), s.pixel_spacing_mm.y()}));
  if (!s.omit_intercept) put_string(0x0028, 0x1052, gdcm::VR::DS, decimals({s.intercept}));
  put_string(0x0028, 0x1053, gdcm::VR::DS, s.slope_text.empty() ? decimals({s.slope}) : s.slope_text);
  put_string(0x0028, 0x0004, gdcm::VR::CS, "MONOCHROME2");
  put_us(0x0028, 0x0002, 1);
  put_us(0x0028, 0x0010, static_cast<uint16_t>(s.rows));
  put_us(0x0028, 0x0011, static_cast<uint16_t>(s.cols));
  put_us(0x0028, 0x0100, 16);
  put_us(0x0028, 0x0101, static_cast<uint16_t>(s.bits_stored));
  put_us(0x0028, 0x0102, static_cast<uint16_t>(s.bits_stored - 1));
  put_us(0x0028, 0x0103, 1);

  std::vector<std::int16_t> pixels = s.stored;
  if (pixels.empty()) {
    for (int r = 0; r < s.rows; ++r)
      for (int c = 0; c < s.cols; ++c) pixels.push_back(pattern_value(s.seed, r, c));
  }
  gdcm::DataElement pixel_data(gdcm::Tag(0x7fe0, 0x0010));
  if (s.mpeg2_pixel_data) {
    gdcm::SmartPointer<gdcm::SequenceOfFragments> fragments = new gdcm::SequenceOfFragments;
    gdcm::Fragment fragment;
    fragment.SetByteValue(reinterpret_cast<const char*>(pixels.data()),
                          static_cast<uint32_t>(pixels.size() * 2));
    fragments->AddFragment(fragment);
    pixel_data.SetVLToUndefined();  // GDCM asserts unless this comes before the VR is set
    pixel_data.SetValue(*fragments);
    pixel_data.SetVR(gdcm::VR::OB);
    f.GetHeader().SetDataSetTransferSyntax(gdcm::TransferSyntax::MPEG2MainProfile);
  } else {
    pixel_data.SetVR(gdcm::VR::OW);
    pixel_data.SetByteValue(reinterpret_cast<const char*>(pixels.data()),
                            static_cast<uint32_t>(pixels.size() * 2));
    f.GetHeader().SetDataSetTransferSyntax(gdcm::TransferSyntax::ExplicitVRLittleEndian);
  }
  ds.Replace(pixel_data);
  writer.SetFileName(file.c_str());
  return writer.Write();
}

void write_synthetic_series(const std::filesystem::path& folder, const SyntheticSlice& base, int count,
                            double spacing_mm) {
  std::filesystem::create_directories(folder);
  const Eigen::Vector3d normal = base.row_cosine.cross(base.col_cosine).normalized();
  for (int k = 0; k < count; ++k) {
    SyntheticSlice s = base;
    s.seed = k;
    s.position_mm = base.position_mm + normal * (k * spacing_mm);
    char name[32];
    // File names deliberately out of position order: slice k is written as file (count - 1 - k).
    std::snprintf(name, sizeof name, "slice%03d.dcm", count - 1 - k);
    write_synthetic_slice(folder / name, s);
  }
}

}  // namespace lftrack::test
