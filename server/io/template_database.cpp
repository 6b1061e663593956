#include "io/template_database.h"
#include "io/template_file.h"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <system_error>

namespace fs = std::filesystem;

namespace fc {

bool isValidTemplateName(const std::string& name) {
  if (name.empty() || name.size() > 64) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
  });
}

void checkTemplateName(const std::string& name) {
  if (isValidTemplateName(name)) return;
  std::string msg = "invalid template name '";
  msg.append(name, 0, std::min<size_t>(name.size(), 80));
  if (name.size() > 80) msg += "...";
  msg += "': names are 1 to 64 characters among A-Z a-z 0-9 _ - (no paths, no dots)";
  throw DatabaseError(msg);
}

TemplateDatabase::TemplateDatabase(std::string directory)
    : dir_(directory.empty() ? std::string(".") : std::move(directory)) {}

std::string TemplateDatabase::pathFor(const std::string& name) const {
  checkTemplateName(name);
  return (fs::path(dir_) / (name + ".h5")).string();
}

bool TemplateDatabase::contains(const std::string& name) const {
  std::error_code ec;
  return fs::is_regular_file(pathFor(name), ec);
}

namespace {

TemplateEntry readEntry(const std::string& name, const std::string& path) {
  TemplateEntry e;
  e.name = name;
  // One call, not two: every reader loads and checksums the whole file.
  const TemplateFileStats s = templateFileStats(path);
  const TemplateHeader& h = s.header;
  e.dimension = h.dimension;
  e.frames = s.frames;
  e.frameRate = h.frameRate;
  e.duration = s.frames > 1 ? double(s.frames - 1) / h.frameRate : 0.0;
  e.avgParticles = s.avgParticles;
  e.regionMin = h.regionMin;
  e.regionMax = h.regionMax;
  e.bytesOnDisk = s.bytesOnDisk;
  return e;
}

}  // namespace

std::vector<TemplateEntry> TemplateDatabase::list() const {
  std::vector<TemplateEntry> out;
  std::error_code ec;
  if (!fs::is_directory(dir_, ec)) return out;
  for (const auto& de : fs::directory_iterator(dir_, ec)) {
    if (!de.is_regular_file(ec) || de.path().extension() != ".h5") continue;
    const std::string name = de.path().stem().string();
    if (!isValidTemplateName(name)) continue;
    try {
      out.push_back(readEntry(name, de.path().string()));
    } catch (const std::exception& ex) {
      TemplateEntry e;
      e.name = name;
      e.error = ex.what();
      out.push_back(e);
    }
  }
  std::sort(out.begin(), out.end(), [](const TemplateEntry& a, const TemplateEntry& b) { return a.name < b.name; });
  return out;
}

TemplateEntry TemplateDatabase::entry(const std::string& name) const {
  const std::string path = pathFor(name);
  if (!contains(name)) throw DatabaseError("no template '" + name + "' in '" + dir_ + "'");
  return readEntry(name, path);
}

template <int D>
std::shared_ptr<const LoadedTemplate<D>> TemplateDatabase::load(const std::string& name,
                                                                const RepulsionOptions& options) {
  const std::string path = pathFor(name);
  std::lock_guard<std::mutex> lock(mutex_);
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw DatabaseError("no template '" + name + "' in '" + dir_ + "'");
  const uint64_t size = fs::file_size(path, ec);
  const int64_t mtime = int64_t(fs::last_write_time(path, ec).time_since_epoch().count());
  const auto key = std::make_pair(name, D);
  auto it = cache_.find(key);
  if (it != cache_.end()) {
    if (auto p = it->second.ptr.lock(); p && it->second.size == size && it->second.mtime == mtime)
      return std::static_pointer_cast<const LoadedTemplate<D>>(p);
  }
  auto loaded = std::make_shared<LoadedTemplate<D>>();
  loaded->name = name;
  const auto t0 = std::chrono::steady_clock::now();
  loaded->tpl = std::make_shared<const Template<D>>(readTemplate<D>(path));
  loaded->readSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  try {
    loaded->accel = TemplateAccel<D>::build(loaded->tpl, options);
  } catch (const std::invalid_argument& e) {
    throw TemplateError(path + ": " + e.what());
  }
  loaded->buildSeconds = loaded->accel.buildSeconds;
  std::shared_ptr<const LoadedTemplate<D>> result = loaded;
  cache_[key] = CacheEntry{std::static_pointer_cast<const void>(result), size, mtime};
  // Drop expired entries so the cache does not grow with names never reloaded.
  for (auto i = cache_.begin(); i != cache_.end();) i = i->second.ptr.expired() ? cache_.erase(i) : std::next(i);
  return result;
}

void TemplateDatabase::remove(const std::string& name) {
  const std::string path = pathFor(name);
  std::lock_guard<std::mutex> lock(mutex_);
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw DatabaseError("no template '" + name + "' in '" + dir_ + "'");
  if (!fs::remove(path, ec) || ec)
    throw DatabaseError("cannot delete '" + path + "': " + (ec ? ec.message() : std::string("not removed")));
  cache_.erase(std::make_pair(name, 2));
  cache_.erase(std::make_pair(name, 3));
}

template std::shared_ptr<const LoadedTemplate<2>> TemplateDatabase::load<2>(const std::string&, const RepulsionOptions&);
template std::shared_ptr<const LoadedTemplate<3>> TemplateDatabase::load<3>(const std::string&, const RepulsionOptions&);

}  // namespace fc
