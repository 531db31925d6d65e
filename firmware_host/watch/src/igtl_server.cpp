#include "lftrack/watch/igtl_server.hpp"

#include <igtlStatusMessage.h>
#include <igtlTransformMessage.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <string>
#include <vector>

#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/loop/realtime_setup.hpp"

namespace lftrack::watch {

using loop::exclude_this_thread_from_allocation_count;
using loop::FeedRecord;
using loop::JournalRecord;
using loop::make_current_thread_best_effort;
using loop::TrackingState;

Eigen::Matrix4d ras_from_lps(const Eigen::Matrix4d& T) {
  const Eigen::Matrix4d F = Eigen::Vector4d(-1, -1, 1, 1).asDiagonal();
  return F * T * F;
}

namespace {

std::int64_t clock_ns(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

// The bytes of one packed message.
std::string packed(igtl::MessageBase* message) {
  message->Pack();
  return {static_cast<const char*>(message->GetPackPointer()), std::size_t(message->GetPackSize())};
}

// Every message carries the time of what it reports (CLOCK_REALTIME, as OpenIGTLink's clients
// read it): without one, a message says 1970, or whatever the library's default is.
void stamp(igtl::MessageBase* message, std::int64_t wall_ns) {
  igtl::TimeStamp::Pointer stamp = igtl::TimeStamp::New();
  stamp->SetTime(static_cast<igtlUint32>(wall_ns / 1'000'000'000), static_cast<igtlUint32>(wall_ns % 1'000'000'000));
  message->SetTimeStamp(stamp);
}

// When a cycle's record happened on the wall clock: the exposure of its newest frame, or the
// cycle's start when it has no frame (CLOCK_MONOTONIC in the record).
std::int64_t record_wall_ns(const JournalRecord& r, std::int64_t wall_minus_mono_ns) {
  const std::int64_t newest_frame_ns = std::max(r.frame_time_ns[0], r.frame_time_ns[1]);
  return (newest_frame_ns > 0 ? newest_frame_ns : r.cycle_start_ns) + wall_minus_mono_ns;
}

std::string transform_message(const char* device, const tracking::Pose& T, std::int64_t wall_ns) {
  const Eigen::Matrix4d ras = ras_from_lps(T.matrix());
  igtl::Matrix4x4 m;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m[r][c] = static_cast<float>(ras(r, c));
  igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
  message->SetDeviceName(device);
  message->SetMatrix(m);
  stamp(message.GetPointer(), wall_ns);
  return packed(message.GetPointer());
}

int status_code(TrackingState state) {
  switch (state) {
    case TrackingState::kTrack:
      return igtl::StatusMessage::STATUS_OK;
    case TrackingState::kAlign:
      return igtl::StatusMessage::STATUS_BUSY;
    case TrackingState::kIdle:
      return igtl::StatusMessage::STATUS_NOT_READY;
    case TrackingState::kHold:
      return igtl::StatusMessage::STATUS_DISABLED;
    case TrackingState::kFault:
      return igtl::StatusMessage::STATUS_HARDWARE_FAILURE;
  }
  return igtl::StatusMessage::STATUS_UNKNOWN_ERROR;
}

std::string status_message(const JournalRecord& r, const std::string& reason, std::int64_t wall_ns) {
  igtl::StatusMessage::Pointer message = igtl::StatusMessage::New();
  message->SetDeviceName("lftrack");
  const auto state = static_cast<TrackingState>(r.state);
  message->SetCode(status_code(state));
  message->SetSubCode(static_cast<igtlInt64>(r.cycle));
  message->SetErrorName(to_string(state));
  message->SetStatusString(reason.c_str());
  stamp(message.GetPointer(), wall_ns);
  return packed(message.GetPointer());
}

}  // namespace

struct IgtlServer::Client {
  int fd = -1;
  std::string pending;  // bytes written to us but not yet taken by the socket
};

Result<std::unique_ptr<IgtlServer>> IgtlServer::start(CycleHub* hub, const IgtlOptions& options) {
  if (hub == nullptr) return invalid_argument("OpenIGTLink: no cycle hub");
  if (options.max_clients < 1 || options.max_clients > 64) return invalid_argument("OpenIGTLink: 1 to 64 clients");
  std::unique_ptr<IgtlServer> s(new IgtlServer);
  s->hub_ = hub;
  s->options_ = options;
  auto fd = open_listening_socket(options.listen, &s->port_);
  if (!fd.ok()) return fd.status().with_context("OpenIGTLink");
  s->listen_fd_ = *fd;
  s->thread_ = std::thread([server = s.get()] { server->run(); });
  return s;
}

IgtlServer::~IgtlServer() {
  stop_.store(true);
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) ::close(listen_fd_);
}

IgtlCounters IgtlServer::counters() const {
  return {clients_now_.load(), clients_total_.load(), clients_dropped_.load(),
          transforms_.load(), statuses_.load(),     skipped_.load()};
}

bool IgtlServer::catch_up(std::uint64_t seq, std::chrono::milliseconds timeout) const {
  const auto until = std::chrono::steady_clock::now() + timeout;
  while (written_through_seq_.load() < seq) {
    if (stop_.load() || std::chrono::steady_clock::now() >= until) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return true;
}

void IgtlServer::run() {
  make_current_thread_best_effort();  // a watcher never competes with the cycle
  exclude_this_thread_from_allocation_count();
  std::vector<Client> clients;
  std::uint64_t after = hub_->status().seq;  // clients see the cycles from their connection on
  std::string state_reason = "connected";
  auto drop = [&](std::size_t i) {
    ::close(clients[i].fd);
    clients.erase(clients.begin() + static_cast<std::ptrdiff_t>(i));
    clients_now_ = static_cast<std::int64_t>(clients.size());
    ++clients_dropped_;
  };
  // Queues `bytes` for every client and writes what each socket takes now.
  auto send_all = [&](const std::string& bytes, std::atomic<std::int64_t>* counter) {
    for (Client& c : clients) {
      if (c.pending.size() + bytes.size() > kMaxPendingBytes) {
        c.pending.clear();
        c.fd = -c.fd - 2;  // stalled: marked, dropped below
        continue;
      }
      c.pending += bytes;
      ++*counter;
    }
  };
  while (!stop_.load()) {
    std::vector<pollfd> fds{{listen_fd_, POLLIN, 0}};
    for (const Client& c : clients) fds.push_back({c.fd, short(POLLIN | (c.pending.empty() ? 0 : POLLOUT)), 0});
    ::poll(fds.data(), fds.size(), 5);
    // New clients, each told the state at once.
    for (int fd; (fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC)) >= 0;) {
      ++clients_total_;
      if (clients.size() >= std::size_t(options_.max_clients)) {
        ::close(fd);
        ++clients_dropped_;
        continue;
      }
      const int on = 1;
      ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &on, sizeof on);
      Client c;
      c.fd = fd;
      const HubStatus now = hub_->status();
      if (now.started) c.pending = status_message(now.last.record, state_reason, clock_ns(CLOCK_REALTIME));
      ++statuses_;
      clients.push_back(std::move(c));
      clients_now_ = static_cast<std::int64_t>(clients.size());  // before the next accept counts in the total
    }
    // What clients send is read and ignored; an end of stream or an error is a disconnect.
    for (std::size_t i = clients.size(); i-- > 0;) {
      char sink[4096];
      const ssize_t n = ::recv(clients[i].fd, sink, sizeof sink, MSG_DONTWAIT);
      if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) drop(i);
    }
    // The cycles since the last pass, in order.
    std::uint64_t first = 0, skipped = 0;
    const std::vector<FeedRecord> records = hub_->records_after(after, 512, &first, &skipped);
    skipped_ += skipped;
    if (!records.empty()) after = first + records.size() - 1;
    const HubOptions& o = hub_->options();
    const std::int64_t wall_minus_mono = clock_ns(CLOCK_REALTIME) - clock_ns(CLOCK_MONOTONIC);
    for (const FeedRecord& f : records) {
      const JournalRecord& r = f.record;
      const std::int64_t wall_ns =
          options_.simulated_clock ? clock_ns(CLOCK_REALTIME) : record_wall_ns(r, wall_minus_mono);
      Eigen::Map<const tracking::Vector6d> delta(r.pose_delta), command(r.command);
      if (f.registered && !clients.empty())
        send_all(transform_message("T_room_from_ct",
                                   tracking::apply_delta(o.nominal_T_room_from_ct, tracking::PoseDelta::from_vector(delta),
                                                         o.registration_origin_room_mm),
                                   wall_ns),
                 &transforms_);
      if (r.command_sent != 0 && !clients.empty())
        send_all(transform_message("Correction",
                                   tracking::apply_delta(tracking::Pose::Identity(),
                                                         tracking::PoseDelta::from_vector(command),
                                                         o.registration_origin_room_mm),
                                   wall_ns),
                 &transforms_);
      if (r.state != r.previous_state) {
        const HubStatus now = hub_->status();
        state_reason = now.transitions.empty() ? "" : now.transitions.back().reason;
        for (const HubTransition& t : now.transitions)
          if (t.cycle == static_cast<std::int64_t>(r.cycle)) state_reason = t.reason;
        if (!clients.empty()) send_all(status_message(r, state_reason, wall_ns), &statuses_);
      }
    }
    // Write what each socket takes; a stalled client (marked above) or a broken one goes.
    for (std::size_t i = clients.size(); i-- > 0;) {
      Client& c = clients[i];
      if (c.fd < 0) {
        c.fd = -c.fd - 2;
        drop(i);
        continue;
      }
      while (!c.pending.empty()) {
        const ssize_t n = ::send(c.fd, c.pending.data(), c.pending.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
        if (n > 0) {
          c.pending.erase(0, std::size_t(n));
          continue;
        }
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) break;
        drop(i);
        break;
      }
    }
    if (std::all_of(clients.begin(), clients.end(), [](const Client& c) { return c.pending.empty(); }))
      written_through_seq_ = after;
  }
  for (Client& c : clients) ::close(c.fd);
  clients_now_ = 0;
}

}  // namespace lftrack::watch
