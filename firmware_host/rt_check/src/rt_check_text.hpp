#pragma once
// What the rt-check files share (not part of lftrack::rt_check's interface): numbers and CPU lists
// as the report writes them, and the host's facts read from /sys and /proc.

#include <optional>
#include <string>
#include <vector>

namespace lftrack::rt_check::rt_check_text {

std::string number_text(double v);                  // "%g"; NaN, inf, -inf by name
std::string cpu_list_text(const std::vector<int>& cpus);  // "0,2,3"; "none" when empty
std::optional<std::string> read_first_line(const char* path);  // of a small file, or nothing
std::vector<int> online_cpus();  // /sys/devices/system/cpu/online, else 0 .. configured - 1

}  // namespace lftrack::rt_check::rt_check_text
