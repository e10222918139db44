#include "firmware_app/status_line.h"

#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cstdio>
#include <mutex>

#include "core/util/clock.h"

namespace uavm::app {

// Wraps stderr output: on a TTY clears the status line before a log message and draws it again after.
struct StatusLine::Sink : spdlog::sinks::base_sink<std::mutex> {
  bool tty = false;
  std::string line;  // the status text currently drawn
  std::string last_error;

  void DrawLocked() {
    if (!tty || line.empty()) return;
    std::fprintf(stderr, "\r\033[K%s", line.c_str());
    std::fflush(stderr);
  }
  void Draw(const std::string& text) {
    std::lock_guard<std::mutex> lock(mutex_);
    line = text;
    DrawLocked();
  }
  void End() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (tty && !line.empty()) std::fputs("\n", stderr);
    line.clear();
  }
  std::string LastError() {
    std::lock_guard<std::mutex> lock(mutex_);
    return last_error;
  }

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    if (msg.level >= spdlog::level::warn) last_error = std::string(msg.payload.begin(), msg.payload.end());
    if (!tty) return;  // the logger's own stderr sink prints it
    spdlog::memory_buf_t buf;
    formatter_->format(msg, buf);
    std::fprintf(stderr, "\r\033[K%.*s", static_cast<int>(buf.size()), buf.data());
    DrawLocked();
  }
  void flush_() override { std::fflush(stderr); }
};

StatusLine::StatusLine() : tty_(::isatty(STDERR_FILENO) == 1), sink_(std::make_shared<Sink>()) {
  sink_->tty = tty_;
  auto& sinks = spdlog::default_logger()->sinks();
  // On a TTY this sink takes over stderr from the default colour sink; elsewhere it only listens.
  if (tty_) sinks.clear();
  sinks.push_back(sink_);
}

StatusLine::~StatusLine() {
  Finish();
}

void StatusLine::Update(const std::string& text, bool force) {
  const long long now = MonotonicNs();
  const double gap_s = static_cast<double>(now - last_ns_) * 1e-9;
  if (tty_) {
    if (!force && gap_s < 0.2) return;
    last_ns_ = now;
    sink_->Draw(text);
    return;
  }
  if (!force && gap_s < log_every_s_) return;
  last_ns_ = now;
  spdlog::info("{}", text);
}

void StatusLine::Finish() {
  sink_->End();
}

std::string StatusLine::last_error() const {
  return sink_->LastError();
}

}  // namespace uavm::app
