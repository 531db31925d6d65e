#pragma once
// The monitor page's files, compiled in from firmware_host/watch/page/ (CMake writes
// monitor_assets.cpp from them at configure time; editing a page file reconfigures).

namespace lftrack::watch {

const char* monitor_page_html();
const char* monitor_page_js();
const char* monitor_page_css();

}  // namespace lftrack::watch
