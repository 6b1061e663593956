#pragma once
// Crash-atomic publishing of files written under temporary names: a set of
// files in one directory moves to its final names all or nothing, even if the
// process is killed at any instant. Used by recordRecipe (all templates of a
// recipe), publishTemplate, a session's history export (NAME.h5 +
// NAME.xdmf), writeTemplate and FrameExporter (publishStaged), saved scenes
// and statistics (publishFile).
//
// How: every temporary name is hidden and carries its owner, the process
// (pid) and a token of that process's start (so a later process that reuses
// the pid is not taken for it):
//   .NAME.stage-<pid>-<token>-<n>       a file being written, becomes NAME
//   .NAME.old-<pid>-<token>-<n>         the replaced NAME, until the set is in place
//   .publish-<pid>-<token>-<n>.journal  the intent of a publish of several files
// A publish of several files fsyncs them, writes and fsyncs the journal
// (each staged file's inode, final name, backup name), links each existing
// final name to its backup, renames the staged files over the final names,
// fsyncs the directory and deletes the journal: that deletion is the commit
// point. recoverPublishing() rolls back a journal left by a dead process and
// deletes the temporary files of dead processes.
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

// The hidden name next to `finalPath` for the file that will become it:
// DIR/.NAME.stage-<pid>-<token>-<n>, unique within the process. It never
// ends in .h5 or .json, so no listing takes a staged file for a real one.
std::string stagingPath(const std::string& finalPath);

// StagedFiles::commit() could not move a file to its final name.
struct PublishError : std::runtime_error {
  PublishError(std::string finalPath, bool exists, const std::string& what)
      : std::runtime_error(what), path(std::move(finalPath)), exists(exists) {}
  std::string path;     // the final name concerned
  bool exists = false;  // it appeared meanwhile and replacing was not allowed
};

class StagedFiles {
 public:
  // replace: a final name that exists is replaced (the old file is kept
  // under a hidden name until every file is in place, then deleted; readers
  // never see the name missing where hard links work). Otherwise each file
  // is moved by a hard link, which fails if the final name exists: an
  // existing file is never replaced, even one that appeared after the caller
  // checked.
  explicit StagedFiles(bool replace) : replace_(replace) {}
  StagedFiles(const StagedFiles&) = delete;
  StagedFiles& operator=(const StagedFiles&) = delete;
  // Not committed (an exception, or commit() failed): every staged file is
  // removed, every final name already moved is removed or given back its
  // old file. If that fails, the journal stays for recoverPublishing().
  ~StagedFiles();

  // Registers a file being written at `staged` (removed on rollback, even if
  // the writer fails halfway) that becomes `final`. Every staged and final
  // name of one StagedFiles must be in the same directory (else
  // std::invalid_argument); use stagingPath(final) for `staged`.
  void stage(const std::string& staged, const std::string& final);
  // Moves every staged file to its final name, all or nothing (also across
  // a crash, see above). Throws PublishError (exists: a final name appeared
  // and !replace; else an I/O error, with strerror) after which the
  // destructor rolls back. A single file is published by its rename: a
  // failed fsync of the directory after it is not reported (the file is in
  // place; only its durability across a power cut is in doubt).
  void commit();

  // Tests only: the process _exit()s with kTestCrashStatus at the step-th
  // crash point reached by commit() from now on (1-based; 0: never), as if
  // killed there. The points are between every two file-system operations.
  static void testCrashAfter(int step);
  static constexpr int kTestCrashStatus = 86;

 private:
  struct Entry {
    std::string staged, final, backup;
    unsigned long long inode = 0;  // of the staged file, once commit() has read it
  };
  void rollback() noexcept;

  bool replace_;
  bool done_ = false;
  std::string dir_;      // of every file; "" until the first stage()
  std::string journal_;  // written by commit(), "" when there is none
  std::vector<Entry> entries_;
};

// Publishes one file that the caller wrote and closed at `staged` (from
// stagingPath(final)) as `final`, the way StagedFiles publishes one file:
// fsynced, then renamed over `final` (replace) or linked to it (never
// replacing). Throws PublishError as commit(), after removing `staged`.
void publishStaged(const std::string& staged, const std::string& final, bool replace);

// Publishes `text` as the file `path` (whose directory must exist) the way
// StagedFiles publishes one file: a reader, or the directory after a crash,
// has the old file or the new one. Throws PublishError as commit() (exists
// when !replace and `path` exists) and std::runtime_error naming `path` if the
// staged file cannot be written.
void publishFile(const std::string& path, const std::string& text, bool replace);

// What recoverPublishing() did.
struct PublishRecovery {
  std::vector<std::string> rolledBack;  // final names given back their old file, or removed (new in an unfinished publish)
  std::vector<std::string> removed;     // temporary files deleted: staged files, backups, journals
  std::vector<std::string> errors;      // what could not be done, with the reason (retried at the next call)
};

// Start-up recovery of one directory (not recursive): every journal of a
// dead process is rolled back (each final name it names holds its old file
// again, or nothing if it had none), then every temporary file of a dead
// process is deleted: the names above and those of earlier versions
// (.NAME.tmp-<pid>[-<n>], .NAME.old-<pid>-<n>, .NAME.export-<pid>-<n>,
// .NAME.rec-<pid>-<n>, NAME.h5.tmp-<pid>[-<n>]). Files of live processes and
// names of any other form are never touched. A name of an earlier version
// carrying this process's pid belongs to a dead process too (this version
// never writes them). A missing directory is not an error. Never throws.
PublishRecovery recoverPublishing(const std::string& dir);

}  // namespace fc
