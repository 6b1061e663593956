#pragma once
// Publishing files that were written under temporary names: a set of files
// moves to its final names all or nothing. Used by recordRecipe (one
// template per capture), publishTemplate (a template recorded from a
// session) and a session's history export (NAME.h5 + NAME.xdmf), so that a
// failure never leaves a partial file under a final name nor loses an
// existing one.
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

// A hidden name next to `finalPath` for the file that will become it:
// DIR/.NAME.<tag>-<pid>-<n>, unique within the process. Its extension is
// never .h5, so a staged template is never listed by the database.
std::string stagingPath(const std::string& finalPath, const std::string& tag);

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
  // under a hidden name until every file is in place, then deleted).
  // Otherwise each file is moved by a hard link, which fails if the final
  // name exists: an existing file is never replaced, even one that appeared
  // after the caller checked.
  explicit StagedFiles(bool replace) : replace_(replace) {}
  StagedFiles(const StagedFiles&) = delete;
  StagedFiles& operator=(const StagedFiles&) = delete;
  // Not committed (an exception, or commit() failed): every staged file is
  // removed, every final name already moved is removed or given back its
  // old file.
  ~StagedFiles();

  // Registers a file being written at `staged` (removed on rollback, even if
  // the writer fails halfway) that becomes `final`.
  void stage(const std::string& staged, const std::string& final);
  // Moves every staged file to its final name, in order. Throws
  // PublishError (exists: a final name appeared and !replace; else the
  // rename failed, with strerror) after which the destructor rolls back.
  void commit();

 private:
  struct Entry {
    std::string staged, final, backup;
    bool created = false;   // the final name now holds the new file
    bool replaced = false;  // ... in place of an existing one (replace)
  };
  void rollback() noexcept;

  bool replace_;
  bool done_ = false;
  std::vector<Entry> entries_;
};

}  // namespace fc
