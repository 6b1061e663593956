#include "io/recipe.h"
#include "io/template_database.h"
#include "io/template_file.h"

#include <unistd.h>
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

namespace fc {

namespace {

double finiteNumber(const nlohmann::json& j, const std::string& path) {
  if (!j.is_number()) throw SceneError(path, "expected a number, got " + std::string(j.type_name()));
  const double v = j.get<double>();
  if (!std::isfinite(v)) throw SceneError(path, "must be finite");
  return v;
}

std::vector<double> vectorOf(const nlohmann::json& j, int dim, const std::string& path) {
  if (!j.is_array()) throw SceneError(path, "expected an array of " + std::to_string(dim) + " numbers");
  if (int(j.size()) != dim)
    throw SceneError(path, "expected " + std::to_string(dim) + " numbers (dimension " + std::to_string(dim) +
                               "), got " + std::to_string(j.size()));
  std::vector<double> v;
  for (int d = 0; d < dim; ++d) v.push_back(finiteNumber(j[d], path + "[" + std::to_string(d) + "]"));
  return v;
}

constexpr size_t kMaxCaptures = 256;

// One capture object; `p` is its key path ("capture" or "capture[i]").
CaptureSpec parseCapture(const nlohmann::json& c, int dim, const std::string& p) {
  if (!c.is_object()) throw SceneError(p, "expected an object {name, region, frames | seconds}");
  for (auto it = c.begin(); it != c.end(); ++it) {
    const std::string& k = it.key();
    if (k != "name" && k != "region" && k != "frames" && k != "seconds" && k != "start")
      throw SceneError(p + "." + k, "unknown key (expected name, region, frames, seconds, start)");
  }
  CaptureSpec s;
  if (!c.contains("name")) throw SceneError(p + ".name", "missing (the template name)");
  if (!c["name"].is_string()) throw SceneError(p + ".name", "expected a string");
  s.name = c["name"].get<std::string>();
  if (!isValidTemplateName(s.name))
    throw SceneError(p + ".name", "invalid template name '" + s.name +
                                      "': 1 to 64 characters among A-Z a-z 0-9 _ -");
  if (!c.contains("region")) throw SceneError(p + ".region", "missing (the capture box {min, max})");
  const nlohmann::json& r = c["region"];
  if (!r.is_object()) throw SceneError(p + ".region", "expected an object {min, max}");
  for (auto it = r.begin(); it != r.end(); ++it)
    if (it.key() != "min" && it.key() != "max")
      throw SceneError(p + ".region." + it.key(), "unknown key (expected min, max)");
  if (!r.contains("min")) throw SceneError(p + ".region.min", "missing");
  if (!r.contains("max")) throw SceneError(p + ".region.max", "missing");
  s.regionMin = vectorOf(r["min"], dim, p + ".region.min");
  s.regionMax = vectorOf(r["max"], dim, p + ".region.max");
  for (int d = 0; d < dim; ++d)
    if (!(s.regionMin[d] < s.regionMax[d]))
      throw SceneError(p + ".region.max[" + std::to_string(d) + "]",
                       "must be greater than region.min[" + std::to_string(d) + "]");
  const bool hasF = c.contains("frames"), hasS = c.contains("seconds");
  if (hasF && hasS) throw SceneError(p + ".seconds", "give either frames or seconds, not both");
  if (!hasF && !hasS) throw SceneError(p + ".frames", "missing (give frames or seconds)");
  if (hasF) {
    const auto& f = c["frames"];
    if (!f.is_number_integer()) throw SceneError(p + ".frames", "expected an integer");
    const long long n = f.get<long long>();
    if (n < 1 || n > 1000000) throw SceneError(p + ".frames", "must be in [1, 1000000], got " + std::to_string(n));
    s.frames = int(n);
  } else {
    const double v = finiteNumber(c["seconds"], p + ".seconds");
    if (!(v > 0) || v > 3600) throw SceneError(p + ".seconds", "must be in (0, 3600]");
    s.seconds = v;
  }
  if (c.contains("start")) {
    s.start = finiteNumber(c["start"], p + ".start");
    if (s.start < 0 || s.start > 3600) throw SceneError(p + ".start", "must be in [0, 3600]");
  }
  return s;
}

// "capture": one object, or an array of 1..kMaxCaptures objects with unique names.
std::vector<CaptureSpec> parseCaptures(const nlohmann::json& c, int dim) {
  std::vector<CaptureSpec> out;
  if (!c.is_array()) {
    if (!c.is_object())
      throw SceneError("capture", "expected an object {name, region, frames | seconds} or an array of them");
    out.push_back(parseCapture(c, dim, "capture"));
    return out;
  }
  if (c.empty()) throw SceneError("capture", "empty array (give at least one capture object)");
  if (c.size() > kMaxCaptures)
    throw SceneError("capture", "at most " + std::to_string(kMaxCaptures) + " captures, got " + std::to_string(c.size()));
  for (size_t i = 0; i < c.size(); ++i) {
    const std::string p = "capture[" + std::to_string(i) + "]";
    CaptureSpec s = parseCapture(c[i], dim, p);
    for (size_t k = 0; k < out.size(); ++k)
      if (out[k].name == s.name)
        throw SceneError(p + ".name", "duplicate template name '" + s.name + "' (also capture[" + std::to_string(k) +
                                          "].name): each capture records its own template");
    out.push_back(std::move(s));
  }
  return out;
}

// Simulation frames of a capture at `frameDt`: the first one and how many.
struct CaptureWindow {
  int first = 0, frames = 0;
  int last() const { return first + frames - 1; }
};
CaptureWindow windowOf(const CaptureSpec& c, double frameDt) {
  CaptureWindow w;
  w.frames = c.frames ? *c.frames : int(std::lround(*c.seconds / frameDt)) + 1;
  w.first = int(std::lround(c.start / frameDt));
  return w;
}

}  // namespace

Recipe parseRecipe(const nlohmann::json& recipe, const std::string& text) {
  if (!recipe.is_object()) throw SceneError("", "a recipe must be a JSON object (a scene plus \"capture\")");
  Recipe r;
  r.scene = recipe;
  if (!recipe.contains("capture"))
    throw SceneError("capture", "missing (a recipe is a scene plus a capture object or an array of them)");
  r.scene.erase("capture");
  r.dimension = sceneDimension(r.scene);
  r.captures = parseCaptures(recipe["capture"], r.dimension);
  // Validate the scene part now, so a bad recipe fails before anything else.
  if (r.dimension == 2) (void)parseScene<2>(r.scene);
  else (void)parseScene<3>(r.scene);
  r.text = text.empty() ? recipe.dump(1) : text;
  return r;
}

Recipe loadRecipe(const std::string& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw SceneError("", "cannot read recipe '" + file + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  return parseRecipe(parseSceneText(text, file), text);
}

template <int D>
std::vector<Template<D>> captureTemplates(const Recipe& recipe, const RecordOptions& options) {
  if (recipe.dimension != D)
    throw std::invalid_argument("recipe is " + std::to_string(recipe.dimension) + "D, capture requested in " +
                                std::to_string(D) + "D");
  if (recipe.captures.empty()) throw std::invalid_argument("recipe without capture");
  const SimulationSetup<D> setup = parseScene<D>(recipe.scene, options.particleRadiusOverride);
  Simulation<D> sim(setup);
  const double frameDt = sim.frameDuration();

  const size_t n = recipe.captures.size();
  std::vector<Template<D>> tpls(n);
  std::vector<CaptureWindow> windows(n);
  std::vector<AABB<D>> regions(n);
  int first = std::numeric_limits<int>::max(), last = 0;
  for (size_t k = 0; k < n; ++k) {
    const CaptureSpec& c = recipe.captures[k];
    windows[k] = windowOf(c, frameDt);
    first = std::min(first, windows[k].first);
    last = std::max(last, windows[k].last());
    TemplateHeader& h = tpls[k].header;
    h.name = c.name;
    h.dimension = D;
    h.frameRate = 1.0 / frameDt;
    h.particleRadius = double(sim.particleRadius());
    h.supportRadius = double(sim.supportRadius());
    h.restDensity = double(setup.phases.at(0).restDensity);
    h.regionMin = c.regionMin;
    h.regionMax = c.regionMax;
    h.recipe = recipe.text;
    h.createdBy = std::string("flowclip ") + FLOWCLIP_VERSION;
    for (int d = 0; d < D; ++d) {
      regions[k].min[d] = Real(c.regionMin[d]);
      regions[k].max[d] = Real(c.regionMax[d]);
    }
    tpls[k].frames.reserve(size_t(windows[k].frames));
  }

  RecordProgress prog;
  prog.frames = last - first + 1;
  auto step = [&]() {
    prog.stats = sim.advanceFrame();
    ++prog.simFrame;
    if (!prog.stats.finite)
      throw std::runtime_error("non-finite position or velocity at simulation frame " +
                               std::to_string(prog.stats.frame) + " (t = " + std::to_string(prog.stats.time) +
                               " s); recording stopped, nothing written");
  };
  for (int i = 0; i < first; ++i) step();
  for (int f = first; f <= last; ++f) {
    if (f > first) step();
    prog.captured = 0;
    const auto& p = sim.fluid;
    for (size_t k = 0; k < n; ++k) {
      if (f < windows[k].first || f > windows[k].last()) continue;
      TemplateFrame<D> fr;
      for (size_t i = 0; i < p.size(); ++i) {
        if (p.kind[i] != uint8_t(ParticleKind::Liquid) || !regions[k].contains(p.x[i])) continue;
        fr.x.push_back(p.x[i]);
        fr.v.push_back(p.v[i]);
        fr.mass.push_back(p.mass[i]);
        fr.phase.push_back(p.phase[i]);
      }
      prog.captured += fr.size();
      tpls[k].frames.push_back(std::move(fr));
    }
    prog.frame = f - first + 1;
    if (options.progress && !options.progress(prog)) throw RecordAborted("recording interrupted, nothing written");
  }
  return tpls;
}

namespace {

// DIR/.NAME<suffix> for DIR/NAME: a hidden file next to `path`, never listed
// as a template (its extension is not .h5).
std::string hiddenSibling(const std::string& path, const std::string& suffix) {
  const std::filesystem::path p(path);
  std::string name = ".";
  name += p.filename().string();
  name += suffix;
  return (p.parent_path() / name).string();
}

// Moves the staged files to their final names, all or nothing (see recordRecipe).
class Commit {
 public:
  explicit Commit(bool force) : force_(force) {}
  Commit(const Commit&) = delete;
  Commit& operator=(const Commit&) = delete;
  ~Commit() {
    if (!done_) rollback();
  }
  // A staged file, removed on rollback until committed.
  void stage(const std::string& staged, const std::string& final) {
    Entry e;
    e.staged = staged;
    e.final = final;
    entries_.push_back(std::move(e));
  }
  void commitAll() {
    namespace fs = std::filesystem;
    static std::atomic<int> counter{0};
    for (Entry& e : entries_) {
      std::error_code ec;
      if (!force_) {
        // A hard link fails if the final name exists: never replaces a file
        // that appeared while recording.
        fs::create_hard_link(e.staged, e.final, ec);
        std::error_code ec2;
        if (ec == std::errc::file_exists || (ec && fs::exists(e.final, ec2)))
          throw DatabaseError("template file '" + e.final +
                              "' was created while recording; use --force to overwrite it");
        if (!ec) {
          e.created = true;
          fs::remove(e.staged, ec);
          continue;
        }
        // No hard links here (some filesystems): the name was free a moment
        // ago, rename.
      } else if (fs::exists(e.final, ec)) {
        // Keep the replaced file under a hidden name until every template is in place.
        e.replaced = true;
        e.backup = backupName(e.final, counter++);
        fs::create_hard_link(e.final, e.backup, ec);
        if (ec) e.backup.clear();
      }
      if (std::rename(e.staged.c_str(), e.final.c_str()) != 0)
        throw TemplateError("template file '" + e.final + "': cannot rename '" + e.staged +
                            "' to the final name: " + std::strerror(errno));
      e.created = true;
    }
    done_ = true;
    for (Entry& e : entries_) {
      std::error_code ec;
      if (!e.backup.empty()) fs::remove(e.backup, ec);
    }
  }

  static std::string backupName(const std::string& final, int k) {
    return hiddenSibling(final, ".old-" + std::to_string(::getpid()) + "-" + std::to_string(k));
  }

 private:
  struct Entry {
    std::string staged, final, backup;
    bool created = false;   // the final name now holds the new file
    bool replaced = false;  // ... in place of an existing one (force)
  };
  void rollback() noexcept {
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
  bool force_;
  bool done_ = false;
  std::vector<Entry> entries_;
};

}  // namespace

RecordResult recordRecipe(const Recipe& recipe, const RecordOptions& options) {
  namespace fs = std::filesystem;
  TemplateDatabase db(options.templatesDir);
  std::vector<std::string> paths;
  for (const CaptureSpec& c : recipe.captures) {
    paths.push_back(db.pathFor(c.name));
    if (!options.force && fs::exists(paths.back()))
      throw DatabaseError("template '" + c.name + "' already exists ('" + paths.back() +
                          "'); use --force to overwrite it");
  }
  std::error_code ec;
  fs::create_directories(options.templatesDir, ec);
  if (ec) throw DatabaseError("cannot create template directory '" + options.templatesDir + "': " + ec.message());

  RecordResult res;
  res.dimension = recipe.dimension;
  auto run = [&](auto dimTag) {
    constexpr int D = decltype(dimTag)::value;
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<Template<D>> tpls = captureTemplates<D>(recipe, options);
    const auto t1 = std::chrono::steady_clock::now();
    res.wallSeconds = std::chrono::duration<double>(t1 - t0).count();
    // Checked again: the simulation may have taken minutes.
    if (!options.force)
      for (size_t k = 0; k < paths.size(); ++k)
        if (fs::exists(paths[k]))
          throw DatabaseError("template '" + recipe.captures[k].name + "' was created while recording ('" +
                              paths[k] + "'); use --force to overwrite it");
    static std::atomic<int> counter{0};
    Commit commit(options.force);
    for (size_t k = 0; k < tpls.size(); ++k) {
      const auto w0 = std::chrono::steady_clock::now();
      const std::string staged =
          hiddenSibling(paths[k], ".rec-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
      commit.stage(staged, paths[k]);
      writeTemplate<D>(staged, tpls[k]);
      RecordedTemplate t;
      t.path = paths[k];
      t.name = recipe.captures[k].name;
      for (const auto& f : tpls[k].frames) {
        t.capturedPerFrame.push_back(f.size());
        t.particleFrames += f.size();
      }
      t.frames = tpls[k].frames.size();
      t.writeSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
      res.templates.push_back(std::move(t));
    }
    commit.commitAll();
    res.writeSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    if (options.keepTemplate)
      for (size_t k = 0; k < tpls.size(); ++k) {
        if constexpr (D == 2) res.templates[k].tpl2 = std::move(tpls[k]);
        else res.templates[k].tpl3 = std::move(tpls[k]);
      }
  };
  if (recipe.dimension == 2) run(std::integral_constant<int, 2>{});
  else run(std::integral_constant<int, 3>{});
  return res;
}

template std::vector<Template<2>> captureTemplates<2>(const Recipe&, const RecordOptions&);
template std::vector<Template<3>> captureTemplates<3>(const Recipe&, const RecordOptions&);

}  // namespace fc
