#include "io/staged_files.h"

#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <system_error>

namespace fc {

namespace {

// DIR/.NAME<suffix> for DIR/NAME.
std::string hiddenSibling(const std::string& path, const std::string& suffix) {
  const std::filesystem::path p(path);
  std::string name = ".";
  name += p.filename().string();
  name += suffix;
  return (p.parent_path() / name).string();
}

std::atomic<int> counter{0};

}  // namespace

std::string stagingPath(const std::string& finalPath, const std::string& tag) {
  return hiddenSibling(finalPath, "." + tag + "-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
}

StagedFiles::~StagedFiles() {
  if (!done_) rollback();
}

void StagedFiles::stage(const std::string& staged, const std::string& final) {
  Entry e;
  e.staged = staged;
  e.final = final;
  entries_.push_back(std::move(e));
}

void StagedFiles::commit() {
  namespace fs = std::filesystem;
  for (Entry& e : entries_) {
    std::error_code ec;
    if (!replace_) {
      fs::create_hard_link(e.staged, e.final, ec);
      std::error_code ec2;
      if (ec == std::errc::file_exists || (ec && fs::exists(e.final, ec2)))
        throw PublishError(e.final, true, "'" + e.final + "' already exists");
      if (!ec) {
        e.created = true;
        fs::remove(e.staged, ec);
        continue;
      }
      // No hard links here (some filesystems): the name was free a moment
      // ago, rename.
    } else if (fs::exists(e.final, ec)) {
      e.replaced = true;
      e.backup = hiddenSibling(e.final, ".old-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
      fs::create_hard_link(e.final, e.backup, ec);
      if (ec) e.backup.clear();
    }
    if (std::rename(e.staged.c_str(), e.final.c_str()) != 0)
      throw PublishError(e.final, false,
                         "cannot rename '" + e.staged + "' to the final name: " + std::strerror(errno));
    e.created = true;
  }
  done_ = true;
  for (Entry& e : entries_) {
    std::error_code ec;
    if (!e.backup.empty()) fs::remove(e.backup, ec);
  }
}

void StagedFiles::rollback() noexcept {
  namespace fs = std::filesystem;
  for (auto it = entries_.rbegin(); it != entries_.rend(); ++it) {
    std::error_code ec;
    fs::remove(it->staged, ec);
    if (!it->created) {
      if (!it->backup.empty()) fs::remove(it->backup, ec);
      continue;
    }
    if (!it->backup.empty()) fs::rename(it->backup, it->final, ec);
    else if (!it->replaced) fs::remove(it->final, ec);
    // Replaced without a backup (no hard links): the old file is gone, the new one stays.
  }
}

}  // namespace fc
