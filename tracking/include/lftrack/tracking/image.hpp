#pragma once
// 2-D images: a non-owning view for kernels and an owning buffer for set-up code.
// Row-major, row 0 at the top; `stride` is in elements between row starts.

#include <cstddef>
#include <type_traits>
#include <vector>

namespace lftrack::tracking {

template <class T>
struct ImageView {
  ImageView() = default;
  ImageView(T* data_, int rows_, int cols_, std::ptrdiff_t stride_)
      : data(data_), rows(rows_), cols(cols_), stride(stride_) {}
  // A view of mutable pixels is also a view of const pixels.
  template <class U, class = std::enable_if_t<std::is_same_v<const U, T>>>
  ImageView(const ImageView<U>& other)  // NOLINT(google-explicit-constructor)
      : data(other.data), rows(other.rows), cols(other.cols), stride(other.stride) {}

  T* data = nullptr;
  int rows = 0;
  int cols = 0;
  std::ptrdiff_t stride = 0;

  T& at(int row, int col) const { return data[row * stride + col]; }
  T* row_ptr(int row) const { return data + row * stride; }
  bool empty() const { return rows <= 0 || cols <= 0; }
};

template <class T>
class Image {
 public:
  Image() = default;
  Image(int rows, int cols, T fill = T{})
      : rows_(rows), cols_(cols), pixels_(static_cast<std::size_t>(rows) * cols, fill) {}

  int rows() const { return rows_; }
  int cols() const { return cols_; }
  T& at(int row, int col) { return pixels_[static_cast<std::size_t>(row) * cols_ + col]; }
  const T& at(int row, int col) const { return pixels_[static_cast<std::size_t>(row) * cols_ + col]; }
  std::vector<T>& pixels() { return pixels_; }
  const std::vector<T>& pixels() const { return pixels_; }
  ImageView<T> view() { return {pixels_.data(), rows_, cols_, cols_}; }
  ImageView<const T> view() const { return {pixels_.data(), rows_, cols_, cols_}; }

 private:
  int rows_ = 0;
  int cols_ = 0;
  std::vector<T> pixels_;
};

// A rectangle of detector pixels: rows [row0, row0 + rows), cols [col0, col0 + cols).
struct PixelWindow {
  int row0 = 0;
  int col0 = 0;
  int rows = 0;
  int cols = 0;

  static PixelWindow full(int detector_rows, int detector_cols) {
    return {0, 0, detector_rows, detector_cols};
  }
  bool inside(int detector_rows, int detector_cols) const {
    return row0 >= 0 && col0 >= 0 && rows > 0 && cols > 0 && row0 + rows <= detector_rows &&
           col0 + cols <= detector_cols;
  }
  bool contains(int row, int col) const {
    return row >= row0 && row < row0 + rows && col >= col0 && col < col0 + cols;
  }
};

}  // namespace lftrack::tracking
