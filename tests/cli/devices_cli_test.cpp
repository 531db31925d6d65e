// `lftrack serve ...` as a user runs it: what a device server says at start.

#include <gtest/gtest.h>

#include <string>

#include "lftrack/studies/plastimatch_peer.hpp"

namespace lftrack::host {
namespace {

// A couch server other hosts can reach gives the warning the monitor page gives (listen_address.hpp:
// reachable_warning); on loopback it gives none.
TEST(ServeCli, ACouchServerOnEveryInterfaceWarnsThatOtherHostsCanMoveTheCouch) {
  std::string out;
  const Status wide = run_process(
      {LFTRACK_BIN_PATH, "serve", "couch", "--modbus", "tcp:0.0.0.0:0", "--duration", "0.2"}, &out);
  ASSERT_TRUE(wide.ok()) << wide.message() << "\n" << out;
  EXPECT_NE(out.find("the modbus couch server listens on 0.0.0.0:"), std::string::npos) << out;
  EXPECT_NE(out.find("(every interface): other hosts can reach it and move the couch"), std::string::npos)
      << out;
  const Status local = run_process(
      {LFTRACK_BIN_PATH, "serve", "couch", "--modbus", "tcp:127.0.0.1:0", "--duration", "0.2"}, &out);
  ASSERT_TRUE(local.ok()) << local.message() << "\n" << out;
  EXPECT_EQ(out.find("other hosts can reach it"), std::string::npos) << "no warning on loopback: " << out;
}

}  // namespace
}  // namespace lftrack::host
