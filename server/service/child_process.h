#pragma once
// A helper program run by the service (flowclip-batch for render jobs): in a
// process group of its own, so that cancelling kills it with everything it
// started (a LocalCluster's workers and their flowclip runs); its stdout read
// line by line, its stderr written to a file.
#include <sys/types.h>

#include <string>
#include <vector>

namespace fc::service {

class ChildProcess {
 public:
  // Starts argv[0] (an absolute path) in `cwd`, stderr into `stderrFile`.
  // Its stdin is a pipe this object holds open: it reads end-of-file when
  // this process dies (how a helper started with flowclip-batch
  // --watch-stdin knows to stop). Throws std::system_error when it cannot start.
  ChildProcess(const std::vector<std::string>& argv, const std::string& cwd, const std::string& stderrFile);
  ~ChildProcess();  // kills the group if it still runs, and reaps the child
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  // The next line of its stdout (without the newline); false at the end of
  // its output. Blocks. Lines longer than 1 MB are cut.
  bool readLine(std::string& line);
  // Signals every process of its group; nothing once it has been reaped
  // (the group's id may then be another's). Not concurrent with wait().
  void signalGroup(int signal);
  // Waits for it to exit, kills what is left of its group, reaps it: its
  // exit status, or 128 + the signal that ended it.
  int wait();

 private:
  pid_t pid_ = -1;
  int out_ = -1;
  int in_ = -1;  // the write end of its stdin
  bool reaped_ = false;
  int status_ = 0;
  std::string buffer_;
};

// The absolute path of `name` in the directories of $PATH, "" if none.
std::string findOnPath(const std::string& name);

}  // namespace fc::service
