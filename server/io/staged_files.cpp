#include "io/staged_files.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <regex>
#include <set>
#include <sstream>
#include <system_error>

namespace fc {

namespace {

namespace fs = std::filesystem;

std::atomic<int> crashCountdown{0};
std::atomic<unsigned> counter{0};

// A test's simulated kill -9 (StagedFiles::testCrashAfter).
void crashPoint() {
  if (crashCountdown.load(std::memory_order_relaxed) > 0 && crashCountdown.fetch_sub(1) == 1)
    ::_exit(StagedFiles::kTestCrashStatus);
}

// ---- owners: a process named by its pid and a token of its start ----------------------

// What /proc/PID/stat says of a process; exists = false if it has no entry.
struct ProcStat {
  bool exists = false;
  bool zombie = false;     // exited, not yet reaped: dead for us
  std::string startTicks;  // field 22, clock ticks since boot
};

ProcStat procStat(long pid) {
  ProcStat s;
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!in || !std::getline(in, line)) return s;
  s.exists = true;
  // The command name (field 2) is in parentheses and may hold anything; fields
  // after the last ')' start at field 3 (state).
  const size_t close = line.rfind(')');
  if (close == std::string::npos) return s;
  std::istringstream rest(line.substr(close + 1));
  std::string field;
  for (int k = 3; k <= 22 && rest >> field; ++k) {
    if (k == 3) s.zombie = field == "Z" || field == "X";
    if (k == 22) s.startTicks = field;
  }
  return s;
}

const std::string& bootId() {
  static const std::string id = [] {
    std::ifstream in("/proc/sys/kernel/random/boot_id");
    std::string s;
    std::getline(in, s);
    return s;
  }();
  return id;
}

// 8 hex digits of FNV-1a over the boot id and the start time: differs for a
// later process that reuses the pid, also after a reboot.
std::string startToken(const std::string& startTicks) {
  uint32_t h = 2166136261u;
  for (char c : bootId() + ":" + startTicks) h = (h ^ uint8_t(c)) * 16777619u;
  char buf[9];
  std::snprintf(buf, sizeof buf, "%08x", h);
  return buf;
}

// "<pid>-<token>" of this process; recomputed after a fork().
std::string ownOwner() {
  static std::mutex m;
  static long cachedPid = -1;
  static std::string cached;
  std::lock_guard lk(m);
  const long pid = long(::getpid());
  if (pid != cachedPid) {
    cachedPid = pid;
    cached = std::to_string(pid) + "-" + startToken(procStat(pid).startTicks);
  }
  return cached;
}

// token: "" for a name of an earlier version, which carries the pid only.
bool processAlive(long pid, const std::string& token) {
  if (pid <= 0) return false;
  if (pid == long(::getpid())) return !token.empty() && std::to_string(pid) + "-" + token == ownOwner();
  const ProcStat s = procStat(pid);
  if (s.exists) return !s.zombie && (token.empty() || startToken(s.startTicks) == token);
  if (procStat(long(::getpid())).exists) return false;  // /proc works: no such process
  return ::kill(pid_t(pid), 0) == 0 || errno == EPERM;  // no /proc: the pid alone decides
}

// ---- names --------------------------------------------------------------------------------

// DIR/.NAME<suffix> for DIR/NAME.
std::string hiddenSibling(const std::string& path, const std::string& suffix) {
  const fs::path p(path);
  std::string name = ".";  // appended, not "." + ...: GCC 12 warns falsely (-Wrestrict) on that
  name += p.filename().string();
  name += suffix;
  return (p.parent_path() / name).string();
}

std::string dirOf(const std::string& path) {
  const fs::path parent = fs::path(path).parent_path();
  return parent.empty() ? std::string(".") : parent.string();
}

enum class NameKind { Other, Staged, Backup, Journal, Legacy };

struct ParsedName {
  NameKind kind = NameKind::Other;
  long pid = 0;
  std::string token;  // "" for Legacy
};

ParsedName parseName(const std::string& name) {
  static const std::regex current(R"(^\..+\.(stage|old)-([0-9]{1,10})-([0-9a-f]{8})-[0-9]+$)");
  static const std::regex journal(R"(^\.publish-([0-9]{1,10})-([0-9a-f]{8})-[0-9]+\.journal$)");
  static const std::regex legacyHidden(R"(^\..+\.(tmp|old|export|rec)-([0-9]{1,10})(-[0-9]+)?$)");
  static const std::regex legacyExport(R"(^[^.].*\.h5\.tmp-([0-9]{1,10})(-[0-9]+)?$)");
  ParsedName p;
  std::smatch m;
  if (std::regex_match(name, m, current)) {
    p.kind = m[1] == "stage" ? NameKind::Staged : NameKind::Backup;
    p.pid = std::stol(m[2]);
    p.token = m[3];
  } else if (std::regex_match(name, m, journal)) {
    p.kind = NameKind::Journal;
    p.pid = std::stol(m[1]);
    p.token = m[2];
  } else if (std::regex_match(name, m, legacyHidden)) {
    p.kind = NameKind::Legacy;
    p.pid = std::stol(m[2]);
  } else if (std::regex_match(name, m, legacyExport)) {
    p.kind = NameKind::Legacy;
    p.pid = std::stol(m[1]);
  }
  return p;
}

// ---- file-system steps ----------------------------------------------------------------------

std::string errnoText(int err) { return std::strerror(err); }

// 0 or errno.
int syncDirectory(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return errno;
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  return rc == 0 ? 0 : err;
}

bool lexists(const std::string& path, struct stat* st = nullptr) {
  struct stat s;
  if (::lstat(path.c_str(), &s) != 0) return false;
  if (st) *st = s;
  return true;
}

// A file system without hard links (link() is refused, not failed).
bool linkUnsupported(int err) { return err == EPERM || err == EOPNOTSUPP || err == ENOTSUP || err == ENOSYS; }

// Writes all of `text` to a new file and fsyncs it; 0 or errno (the file may
// then exist, partly written).
int writeNewFile(const std::string& path, const std::string& text) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd < 0) return errno;
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = n < 0 ? errno : EIO;
      ::close(fd);
      return err;
    }
    done += size_t(n);
  }
  const int rc = ::fsync(fd);
  const int err = errno;
  if (::close(fd) != 0 && rc == 0) return errno;
  return rc == 0 ? 0 : err;
}

// ---- the journal ---------------------------------------------------------------------------
//   flowclip-publish 1
//   <inode> <final> <staged> <backup or ->     one line per file, names %-escaped
//   end
// Without its "end" line a journal was cut short: no file had moved yet.

constexpr const char* kJournalHeader = "flowclip-publish 1";

std::string escapeName(const std::string& s) {
  std::string out;
  for (unsigned char c : s) {
    if (c <= 0x20 || c == '%' || c == 0x7f) {
      char buf[4];
      std::snprintf(buf, sizeof buf, "%%%02x", c);
      out += buf;
    } else {
      out += char(c);
    }
  }
  return out;
}

bool unescapeName(const std::string& s, std::string& out) {
  out.clear();
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] != '%') {
      out += s[i];
      continue;
    }
    if (i + 2 >= s.size()) return false;
    const std::string hex = s.substr(i + 1, 2);
    if (!std::isxdigit(uint8_t(hex[0])) || !std::isxdigit(uint8_t(hex[1]))) return false;
    out += char(std::stoi(hex, nullptr, 16));
    i += 2;
  }
  return true;
}

// A bare name inside the directory: never a path elsewhere.
bool plainName(const std::string& s) {
  return !s.empty() && s != "." && s != ".." && s.find('/') == std::string::npos && s.find('\0') == std::string::npos;
}

struct JournalEntry {
  unsigned long long inode = 0;
  std::string final, staged, backup;  // names in the directory; backup "" if none
};

std::string journalText(const std::vector<JournalEntry>& entries) {
  std::string t = std::string(kJournalHeader) + "\n";
  for (const JournalEntry& e : entries)
    t += std::to_string(e.inode) + " " + escapeName(e.final) + " " + escapeName(e.staged) + " " +
         (e.backup.empty() ? std::string("-") : escapeName(e.backup)) + "\n";
  return t + "end\n";
}

enum class JournalState { Complete, Incomplete, Invalid };

JournalState readJournal(const std::string& path, std::vector<JournalEntry>& entries) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return JournalState::Invalid;
  std::string line;
  if (!std::getline(in, line)) return JournalState::Incomplete;  // empty: cut short before its header
  if (line != kJournalHeader)  // a cut-short header, or not ours
    return std::string(kJournalHeader).rfind(line, 0) == 0 && in.peek() == EOF ? JournalState::Incomplete
                                                                               : JournalState::Invalid;
  while (std::getline(in, line)) {
    if (line == "end") return in.peek() == EOF ? JournalState::Complete : JournalState::Invalid;
    std::istringstream ls(line);
    std::string inode, final, staged, backup, extra;
    JournalEntry e;
    if (!(ls >> inode >> final >> staged >> backup) || (ls >> extra)) return JournalState::Incomplete;
    if (inode.find_first_not_of("0123456789") != std::string::npos) return JournalState::Invalid;
    e.inode = std::stoull(inode);
    if (!unescapeName(final, e.final) || !unescapeName(staged, e.staged)) return JournalState::Invalid;
    if (backup != "-" && !unescapeName(backup, e.backup)) return JournalState::Invalid;
    entries.push_back(std::move(e));
  }
  return JournalState::Incomplete;
}

// Gives `final` back what it held before the publish: the backup if there is
// one, nothing if the publish created it. Idempotent. Returns false (and an
// error) if a step failed.
bool rollbackEntry(const std::string& dir, const JournalEntry& e, bool& restored, std::string& error) {
  restored = false;
  const std::string final = (fs::path(dir) / e.final).string();
  const std::string backup = e.backup.empty() ? std::string() : (fs::path(dir) / e.backup).string();
  struct stat st;
  const bool finalExists = lexists(final, &st);
  const bool isNew = finalExists && e.inode != 0 && (unsigned long long)(st.st_ino) == e.inode;
  const bool haveBackup = !backup.empty() && lexists(backup);
  if (haveBackup && (isNew || !finalExists)) {
    if (::rename(backup.c_str(), final.c_str()) != 0) {
      error = "cannot restore '" + final + "' from '" + backup + "': " + errnoText(errno);
      return false;
    }
    restored = true;
  } else if (isNew) {
    if (::unlink(final.c_str()) != 0 && errno != ENOENT) {
      error = "cannot remove '" + final + "': " + errnoText(errno);
      return false;
    }
    restored = true;
  } else if (haveBackup) {
    ::unlink(backup.c_str());  // a second link of the final name's file
  }
  const std::string staged = (fs::path(dir) / e.staged).string();
  if (::unlink(staged.c_str()) != 0 && errno != ENOENT) {
    error = "cannot remove '" + staged + "': " + errnoText(errno);
    return false;
  }
  return true;
}

}  // namespace

std::string stagingPath(const std::string& finalPath) {
  return hiddenSibling(finalPath, ".stage-" + ownOwner() + "-" + std::to_string(counter++));
}

void StagedFiles::testCrashAfter(int step) { crashCountdown = step; }

StagedFiles::~StagedFiles() {
  if (!done_) rollback();
}

void StagedFiles::stage(const std::string& staged, const std::string& final) {
  const std::string dir = dirOf(final);
  if (dirOf(staged) != dir || (!dir_.empty() && dir != dir_))
    throw std::invalid_argument("cannot publish '" + final + "' from '" + staged +
                                "': the files of one publish must share one directory");
  dir_ = dir;
  Entry e;
  e.staged = staged;
  e.final = final;
  entries_.push_back(std::move(e));
}

void StagedFiles::commit() {
  if (entries_.empty()) {
    done_ = true;
    return;
  }
  crashPoint();  // staged files written
  for (Entry& e : entries_) {
    const int fd = ::open(e.staged.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) throw PublishError(e.final, false, "cannot open '" + e.staged + "': " + errnoText(errno));
    struct stat st;
    const bool ok = ::fsync(fd) == 0 && ::fstat(fd, &st) == 0;
    const int err = errno;
    ::close(fd);
    if (!ok) throw PublishError(e.final, false, "cannot flush '" + e.staged + "' to disk: " + errnoText(err));
    e.inode = (unsigned long long)(st.st_ino);
  }
  crashPoint();

  // One file needs no journal: a rename is atomic by itself.
  if (entries_.size() > 1) {
    const std::string owner = ownOwner();
    std::vector<JournalEntry> lines;
    for (Entry& e : entries_) {
      if (replace_) e.backup = hiddenSibling(e.final, ".old-" + owner + "-" + std::to_string(counter++));
      lines.push_back({e.inode, fs::path(e.final).filename().string(), fs::path(e.staged).filename().string(),
                       fs::path(e.backup).filename().string()});
    }
    const std::string journal =
        (fs::path(dir_) / (".publish-" + owner + "-" + std::to_string(counter++) + ".journal")).string();
    int err = writeNewFile(journal, journalText(lines));
    if (err == 0 || lexists(journal)) journal_ = journal;  // rollback() removes it
    if (err == 0) err = syncDirectory(dir_);
    if (err != 0)
      throw PublishError(entries_.front().final, false, "cannot write '" + journal + "': " + errnoText(err));
    crashPoint();
  }

  for (Entry& e : entries_) {
    if (!replace_) {
      if (::link(e.staged.c_str(), e.final.c_str()) == 0) {
        crashPoint();
        ::unlink(e.staged.c_str());
        crashPoint();
        continue;
      }
      const int err = errno;
      if (err == EEXIST || lexists(e.final)) throw PublishError(e.final, true, "'" + e.final + "' already exists");
      if (!linkUnsupported(err))
        throw PublishError(e.final, false, "cannot link '" + e.staged + "' to the final name: " + errnoText(err));
      // No hard links here: the name was free a moment ago, rename.
    } else if (struct stat st; !e.backup.empty() && lexists(e.final, &st)) {
      if (S_ISDIR(st.st_mode)) throw PublishError(e.final, false, "'" + e.final + "' is a directory");
      if (::link(e.final.c_str(), e.backup.c_str()) != 0) {
        const int err = errno;
        // Without hard links the old file moves aside: the name is briefly missing.
        if (!linkUnsupported(err) || ::rename(e.final.c_str(), e.backup.c_str()) != 0)
          throw PublishError(e.final, false, "cannot keep the old '" + e.final + "': " + errnoText(err));
      }
      crashPoint();
    }
    if (::rename(e.staged.c_str(), e.final.c_str()) != 0)
      throw PublishError(e.final, false,
                         "cannot rename '" + e.staged + "' to the final name: " + errnoText(errno));
    crashPoint();
  }
  // One file: its rename was the commit point; rolling back now would leave
  // neither the file it replaced nor the new one.
  if (entries_.size() == 1) done_ = true;
  if (const int err = syncDirectory(dir_); err != 0 && !done_)
    throw PublishError(entries_.front().final, false, "cannot flush directory '" + dir_ + "': " + errnoText(err));
  crashPoint();
  if (!journal_.empty()) {
    // The commit point: from here on, recovery keeps the new files.
    if (::unlink(journal_.c_str()) != 0)
      throw PublishError(entries_.front().final, false, "cannot remove '" + journal_ + "': " + errnoText(errno));
    journal_.clear();
    crashPoint();
    syncDirectory(dir_);  // durable now; the files are published either way
  }
  done_ = true;
  for (Entry& e : entries_) {
    if (e.backup.empty()) continue;
    ::unlink(e.backup.c_str());
    crashPoint();
  }
}

void StagedFiles::rollback() noexcept {
  bool ok = true;
  for (auto it = entries_.rbegin(); it != entries_.rend(); ++it) {
    JournalEntry e{it->inode, fs::path(it->final).filename().string(), fs::path(it->staged).filename().string(),
                   it->backup.empty() ? std::string() : fs::path(it->backup).filename().string()};
    bool restored = false;
    std::string error;
    try {
      ok = rollbackEntry(dir_, e, restored, error) && ok;
    } catch (...) {
      ok = false;
    }
  }
  // Kept if a step failed: recoverPublishing() finishes it after this process.
  if (!journal_.empty() && ok) ::unlink(journal_.c_str());
  if (!dir_.empty()) syncDirectory(dir_);
}

void publishStaged(const std::string& staged, const std::string& final, bool replace) {
  StagedFiles files(replace);
  files.stage(staged, final);
  files.commit();
}

void publishFile(const std::string& path, const std::string& text, bool replace) {
  const std::string staged = stagingPath(path);
  if (const int err = writeNewFile(staged, text); err != 0) {
    ::unlink(staged.c_str());  // partly written
    throw std::runtime_error("cannot write '" + path + "': " + errnoText(err));
  }
  publishStaged(staged, path, replace);
}

PublishRecovery recoverPublishing(const std::string& dir) {
  PublishRecovery r;
  auto list = [&] {
    std::vector<std::string> names;
    std::error_code ec;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
      names.push_back(it->path().filename().string());
    return names;
  };
  const std::vector<std::string> first = list();
  bool changed = false;

  // Journals first: they say which final names to give back.
  std::set<std::string> keep;  // owners of a journal that could not be finished: their files stay
  for (const std::string& name : first) {
    const ParsedName p = parseName(name);
    if (p.kind != NameKind::Journal || processAlive(p.pid, p.token)) continue;
    const std::string path = (fs::path(dir) / name).string();
    std::vector<JournalEntry> entries;
    const JournalState state = readJournal(path, entries);
    bool ok = true;
    const std::string owner = std::to_string(p.pid) + "-" + p.token;
    if (state == JournalState::Invalid) {
      r.errors.push_back("'" + path + "' is not a journal this version can read; left as it is");
      keep.insert(owner);
      continue;
    }
    if (state == JournalState::Complete) {
      for (const JournalEntry& e : entries) {
        // Only our own temporary names, of the journal's owner, are acted on.
        const ParsedName s = parseName(e.staged), b = parseName(e.backup);
        const bool valid = plainName(e.final) && s.kind == NameKind::Staged && s.pid == p.pid && s.token == p.token &&
                           (e.backup.empty() || (b.kind == NameKind::Backup && b.pid == p.pid && b.token == p.token));
        if (!valid) {
          r.errors.push_back("'" + path + "' names a file outside its publish; left as it is");
          ok = false;
          break;
        }
      }
      for (size_t k = entries.size(); ok && k-- > 0;) {
        bool restored = false;
        std::string error;
        if (!rollbackEntry(dir, entries[k], restored, error)) {
          r.errors.push_back(error);
          ok = false;
        }
        if (restored) r.rolledBack.push_back((fs::path(dir) / entries[k].final).string());
        changed = true;
      }
    }
    // Incomplete: cut short while being written, before any file moved.
    if (ok && ::unlink(path.c_str()) == 0) {
      r.removed.push_back(path);
      changed = true;
    } else {
      if (ok) r.errors.push_back("cannot remove '" + path + "': " + errnoText(errno));
      keep.insert(owner);
    }
  }

  // Then every temporary file of a dead process.
  for (const std::string& name : list()) {
    const ParsedName p = parseName(name);
    if (p.kind == NameKind::Other || p.kind == NameKind::Journal) continue;
    if (!p.token.empty() && keep.count(std::to_string(p.pid) + "-" + p.token)) continue;
    if (processAlive(p.pid, p.token)) continue;
    const std::string path = (fs::path(dir) / name).string();
    struct stat st;
    if (!lexists(path, &st)) continue;
    if (S_ISDIR(st.st_mode)) {
      // Of folders, only one staged by this version (an export job's) is ours.
      if (p.kind != NameKind::Staged) continue;
      std::error_code ec;
      fs::remove_all(path, ec);
      if (ec) r.errors.push_back("cannot remove '" + path + "': " + ec.message());
      else r.removed.push_back(path), changed = true;
      continue;
    }
    if (::unlink(path.c_str()) == 0) {
      r.removed.push_back(path);
      changed = true;
    } else if (errno != ENOENT) {
      r.errors.push_back("cannot remove '" + path + "': " + errnoText(errno));
    }
  }
  if (changed) syncDirectory(dir);
  return r;
}

}  // namespace fc
