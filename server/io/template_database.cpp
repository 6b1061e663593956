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

TemplateDatabase::TemplateDatabase(std::string directory, size_t memoryBytes)
    : dir_(directory.empty() ? std::string(".") : std::move(directory)), memoryBytes_(memoryBytes) {}

std::string TemplateDatabase::pathFor(const std::string& name) const {
  checkTemplateName(name);
  return (fs::path(dir_) / (name + ".h5")).string();
}

bool TemplateDatabase::contains(const std::string& name) const {
  std::error_code ec;
  return fs::is_regular_file(pathFor(name), ec);
}

namespace {

// Bytes a template takes decoded per byte of its file, at most: files hold
// 4 to 6.5 bytes per particle-frame, TemplateAccel 53 to 65 and its cells.
constexpr uint64_t kMaxDecodedPerFileByte = 24;

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
  const auto seconds = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); };
  try {
    // Decoded, a template takes a bounded multiple of its file: small files
    // are read whole without looking further. Larger ones are opened as a
    // stream (the whole file verified, its index read), and streamed when
    // their frames would not fit the budget decoded.
    std::shared_ptr<TemplateStream<D>> stream;
    if (size * kMaxDecodedPerFileByte > memoryBytes_ && startsWithChecksumBlock(path))
      stream = std::make_shared<TemplateStream<D>>(path);
    if (stream && stream->particleFrames() * TemplateAccel<D>::kBytesPerParticleFrame > memoryBytes_) {
      auto header = std::make_shared<Template<D>>();
      header->header = stream->header();
      header->streamedFrames = stream->frameCount();
      loaded->tpl = header;
      loaded->readSeconds = seconds();
      loaded->accel = TemplateAccel<D>::streamed(loaded->tpl, stream, memoryBytes_, options);
    } else {
      if (stream) {
        auto whole = std::make_shared<Template<D>>();
        whole->header = stream->header();
        whole->frames.reserve(stream->frameCount());
        for (size_t f = 0; f < stream->frameCount(); ++f) whole->frames.push_back(stream->readFrame(f));
        loaded->tpl = whole;
      } else {
        loaded->tpl = std::make_shared<const Template<D>>(readTemplate<D>(path));
      }
      loaded->readSeconds = seconds();
      loaded->accel = TemplateAccel<D>::build(loaded->tpl, options);
    }
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

namespace {
template <int D>
void addStreamed(const std::string& name, const std::shared_ptr<const void>& p,
                 std::vector<TemplateDatabase::Streamed>& out) {
  const auto& lt = *std::static_pointer_cast<const LoadedTemplate<D>>(p);
  if (!lt.streamed()) return;
  const auto c = lt.accel.cacheStats();
  out.push_back({name, D, lt.accel.frameCount(), c.cacheBytes, c.peakBytes, c.loads, c.hits, c.loadSeconds});
}
}  // namespace

std::vector<TemplateDatabase::Streamed> TemplateDatabase::streamedTemplates() const {
  std::vector<Streamed> out;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [key, entry] : cache_) {
    const auto p = entry.ptr.lock();
    if (!p) continue;
    if (key.second == 2) addStreamed<2>(key.first, p, out);
    else addStreamed<3>(key.first, p, out);
  }
  return out;
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
