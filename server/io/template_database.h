#pragma once
// The template database (paper §3.2): a directory of template files
// NAME.h5 (format in templates/README.md, io/template_file.h).
//
// Names are restricted to [A-Za-z0-9_-]{1,64}, so NAME.h5 always lies
// directly inside the directory: no name can reach a path outside it. Every
// method that takes a name validates it first and throws DatabaseError
// without touching the filesystem when it is invalid.
//
// Loading is shared: load<D>(name) returns the same LoadedTemplate while any
// caller still holds it (a cache of weak pointers). A cached entry is reused
// only if the file's size and modification time are unchanged, so a template
// re-recorded with --force is loaded afresh (holders of the old one keep it).
// The database is thread-safe; loads are serialised by one mutex, so two
// concurrent loads of the same name also share one result.
#include "control/template.h"
#include "control/template_grids.h"

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

// Invalid name, missing template, existing template (when not overwriting).
struct DatabaseError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// true iff name matches [A-Za-z0-9_-]{1,64}.
bool isValidTemplateName(const std::string& name);
// Throws DatabaseError explaining the rule when the name is invalid.
void checkTemplateName(const std::string& name);

struct TemplateEntry {
  std::string name;
  int dimension = 0;
  size_t frames = 0;
  double frameRate = 0;
  double duration = 0;               // s, (frames - 1) / frameRate
  double avgParticles = 0;           // per frame
  std::vector<double> regionMin, regionMax;
  uint64_t bytesOnDisk = 0;
  std::string error;                 // non-empty: the file could not be read (other fields unset)
};

// A template ready for control: its particles plus the per-frame grids and
// repulsion layer, built at load, or streamed from its file (tpl holds the
// header only; accel reads and builds frames as control asks for them).
template <int D>
struct LoadedTemplate {
  std::string name;
  std::shared_ptr<const Template<D>> tpl;
  TemplateAccel<D> accel;           // refers to *tpl (and keeps it alive)
  double readSeconds = 0;           // reading and decoding the file (streamed: verifying it and its index)
  double buildSeconds = 0;          // grids + repulsion layer (accel.buildSeconds; 0 when streamed)
  bool streamed() const { return accel.isStreamed(); }
  const Template<D>& templ() const { return *tpl; }
};

// How much of the memory a template may take decoded before it is streamed
// instead (the default of `--template-memory`, MB): a template whose frames,
// grids and repulsion layers would need more is read frame by frame, with at
// most this much of it kept.
inline constexpr double kDefaultTemplateMemoryMB = 4096;

class TemplateDatabase {
 public:
  // memoryBytes: the budget above, per template.
  explicit TemplateDatabase(std::string directory = "templates",
                            size_t memoryBytes = size_t(kDefaultTemplateMemoryMB * 1024 * 1024));
  size_t memoryBytes() const { return memoryBytes_; }

  const std::string& directory() const { return dir_; }
  // DIR/NAME.h5 (name validated).
  std::string pathFor(const std::string& name) const;
  bool contains(const std::string& name) const;

  // Every NAME.h5 with a valid name in the directory, sorted by name. A file
  // that cannot be read is listed with `error` set. A missing directory lists
  // nothing.
  std::vector<TemplateEntry> list() const;
  // One entry; throws DatabaseError if the template does not exist and
  // TemplateError if the file is unreadable.
  TemplateEntry entry(const std::string& name) const;

  // Throws DatabaseError (invalid name, no such template) or TemplateError
  // (unreadable file, dimension other than D).
  template <int D>
  std::shared_ptr<const LoadedTemplate<D>> load(const std::string& name, const RepulsionOptions& options = {});

  // The templates loaded streamed and still held by someone, with their caches' figures.
  struct Streamed {
    std::string name;
    int dimension = 0;
    size_t frames = 0;
    size_t cacheBytes = 0, peakBytes = 0, loads = 0, hits = 0;
    double loadSeconds = 0;
  };
  std::vector<Streamed> streamedTemplates() const;

  // Deletes DIR/NAME.h5 only. Throws DatabaseError if it does not exist.
  // Holders of a loaded copy keep it.
  void remove(const std::string& name);

 private:
  struct CacheEntry {
    std::weak_ptr<const void> ptr;
    uint64_t size = 0;
    int64_t mtime = 0;
  };
  std::string dir_;
  size_t memoryBytes_;
  mutable std::mutex mutex_;
  std::map<std::pair<std::string, int>, CacheEntry> cache_;  // (name, D)
};

}  // namespace fc
