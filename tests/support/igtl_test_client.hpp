#pragma once
// A test's OpenIGTLink client: the library's own client socket and message classes (as 3D
// Slicer's OpenIGTLinkIF uses them), reading one whole message at a time with a deadline.

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <igtlClientSocket.h>
#include <igtlMessageHeader.h>
#include <igtlStatusMessage.h>
#include <igtlTransformMessage.h>

namespace lftrack::test {

// One message as received: TRANSFORM (its matrix) or STATUS (code, sub-code, names).
struct IgtlMessage {
  std::string type, device;
  Eigen::Matrix4d matrix = Eigen::Matrix4d::Zero();
  int code = 0;
  std::int64_t subcode = 0;
  std::string error_name, status;
  double timestamp_s = 0;  // the header's time stamp (seconds since 1970)
};

class IgtlClient {
 public:
  // Connects to 127.0.0.1:port.
  explicit IgtlClient(int port) : socket_(igtl::ClientSocket::New()) {
    connected_ = socket_->ConnectToServer("127.0.0.1", port) == 0;
    if (connected_) socket_->SetReceiveTimeout(200);
  }
  bool connected() const { return connected_; }
  bool closed() const { return closed_; }  // the server closed the connection
  // The next message, or nothing when none began within `wait` or the connection closed. A message
  // that has begun is always read whole (a stream is never left in the middle of one).
  std::optional<IgtlMessage> next(std::chrono::milliseconds wait = std::chrono::milliseconds(3000)) {
    const auto deadline = std::chrono::steady_clock::now() + wait;
    igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
    header->InitPack();
    if (!read(header->GetPackPointer(), header->GetPackSize(), deadline)) return std::nullopt;
    header->Unpack();
    IgtlMessage m;
    m.type = header->GetDeviceType();
    m.device = header->GetDeviceName();
    igtl::TimeStamp::Pointer stamp = igtl::TimeStamp::New();
    header->GetTimeStamp(stamp);
    m.timestamp_s = stamp->GetTimeStamp();
    if (m.type == "TRANSFORM") {
      igtl::TransformMessage::Pointer t = igtl::TransformMessage::New();
      t->SetMessageHeader(header);
      t->AllocatePack();
      if (!read(t->GetPackBodyPointer(), t->GetPackBodySize(), deadline)) return std::nullopt;
      EXPECT_TRUE(t->Unpack(1) & igtl::MessageHeader::UNPACK_BODY) << "CRC";
      igtl::Matrix4x4 matrix;
      t->GetMatrix(matrix);
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m.matrix(r, c) = matrix[r][c];
    } else if (m.type == "STATUS") {
      igtl::StatusMessage::Pointer s = igtl::StatusMessage::New();
      s->SetMessageHeader(header);
      s->AllocatePack();
      if (!read(s->GetPackBodyPointer(), s->GetPackBodySize(), deadline)) return std::nullopt;
      EXPECT_TRUE(s->Unpack(1) & igtl::MessageHeader::UNPACK_BODY) << "CRC";
      m.code = s->GetCode();
      m.subcode = s->GetSubCode();
      m.error_name = s->GetErrorName();
      m.status = s->GetStatusString();
    } else {
      std::vector<char> body(std::size_t(header->GetBodySizeToRead()));  // another type: skipped whole
      if (!body.empty() && !read(body.data(), int(body.size()), deadline)) return std::nullopt;
    }
    return m;
  }

 private:
  // Reads `length` bytes; gives up at `deadline` only before the first of them.
  bool read(void* data, int length, std::chrono::steady_clock::time_point deadline) {
    int got = 0;
    while (got < length) {
      const int n = socket_->Receive(static_cast<char*>(data) + got, length - got, 0);
      if (n == 0) {
        closed_ = true;
        return false;
      }
      if (n > 0) got += n;
      if (got == 0 && std::chrono::steady_clock::now() > deadline) return false;
    }
    return true;
  }
  igtl::ClientSocket::Pointer socket_;
  bool connected_ = false, closed_ = false;
};

}  // namespace lftrack::test
