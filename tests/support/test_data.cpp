#include "test_data.hpp"

#include <unistd.h>

namespace lftrack::test {

TempDir::TempDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name = info ? std::string(info->test_suite_name()) + "." + info->name() : "lftrack";
  for (char& c : name)
    if (c == '/') c = '_';
  path_ =
      std::filesystem::temp_directory_path() / ("lftrack-test-" + name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(path_);
  std::filesystem::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ec;
  std::filesystem::remove_all(path_, ec);
}

}  // namespace lftrack::test
