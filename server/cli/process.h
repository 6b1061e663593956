#pragma once
// The flowclip process itself: its peak memory, its own executable, child
// processes, and Ctrl-C.
#include <string>
#include <vector>

namespace fc::cli {

// Peak resident set size of this process (VmHWM), MB.
double peakRssMb();
// The running executable's absolute path ("flowclip" if it cannot be read).
std::string selfExecutable();
// Runs args[0] (an absolute path) with args in a child process and waits:
// its exit status, -1 if it could not start or did not exit normally.
int runChild(const std::vector<std::string>& args);

// While a guard lives, Ctrl-C (SIGINT) only sets requested(), so a long
// command can stop cleanly after its current frame; the previous handler is
// restored when the guard ends.
class InterruptGuard {
 public:
  InterruptGuard();
  ~InterruptGuard();
  InterruptGuard(const InterruptGuard&) = delete;
  InterruptGuard& operator=(const InterruptGuard&) = delete;
  static bool requested();

 private:
  void (*previous_)(int);
};

}  // namespace fc::cli
