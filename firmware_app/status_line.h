#pragma once
#include <memory>
#include <string>

namespace uavm::app {

// Operator feedback in the terminal. On a TTY (isatty(stderr)) a one-line status rewritten in place with \r; log
// messages are printed above it (the line is cleared, the message written, the line drawn again). Otherwise plain
// periodic log lines. Also remembers the last warning/error message (for /status.json).
class StatusLine {
 public:
  StatusLine();  // installs the log sink
  ~StatusLine();
  StatusLine(const StatusLine&) = delete;
  StatusLine& operator=(const StatusLine&) = delete;

  [[nodiscard]] bool tty() const { return tty_; }
  // Redraws the line (TTY, at most 5 times a second) or logs it (not a TTY, at most every `log_every_s`).
  void Update(const std::string& text, bool force = false);
  void Finish();  // ends the line (TTY) so that what follows starts on a fresh one
  [[nodiscard]] std::string last_error() const;

  struct Sink;

 private:
  bool tty_ = false;
  double log_every_s_ = 5.0;
  long long last_ns_ = 0;
  std::shared_ptr<Sink> sink_;
};

}  // namespace uavm::app
