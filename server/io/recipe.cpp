#include "io/recipe.h"
#include "io/json_access.h"
#include "io/staged_files.h"
#include "io/template_database.h"
#include "io/template_file.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

namespace fc {

namespace {

using namespace json_access;

std::vector<double> vectorOf(const nlohmann::json& j, int dim, const std::string& path) {
  expectType(j.is_array(), j, path, dim == 2 ? "an array of 2 numbers" : "an array of 3 numbers");
  if (int(j.size()) != dim)
    fail(path, "expected " + std::to_string(dim) + " numbers (dimension " + std::to_string(dim) + "), got " +
                   std::to_string(j.size()));
  std::vector<double> v;
  for (int d = 0; d < dim; ++d) v.push_back(getNumber(j[d], indexPath(path, size_t(d))));
  return v;
}

constexpr size_t kMaxCaptures = 256;
constexpr double kMaxCaptureSeconds = 3600;

// One capture object; `p` is its key path ("capture" or "capture[i]").
CaptureSpec parseCapture(const nlohmann::json& c, int dim, const std::string& p) {
  expectType(c.is_object(), c, p, "an object {name, region, frames | seconds}");
  checkKeys(c, p, {"name", "region", "frames", "seconds", "start"});
  CaptureSpec s;
  const std::string np = keyPath(p, "name");
  s.name = getString(required(c, p, "name", "the template name"), np);
  if (!isValidTemplateName(s.name))
    fail(np, "invalid template name '" + s.name + "': 1 to 64 characters among A-Z a-z 0-9 _ -");
  const std::string rp = keyPath(p, "region");
  const nlohmann::json& r = expectObject(required(c, p, "region", "the capture box {min, max}"), rp);
  checkKeys(r, rp, {"min", "max"});
  s.regionMin = vectorOf(required(r, rp, "min", "lower corner, m"), dim, keyPath(rp, "min"));
  s.regionMax = vectorOf(required(r, rp, "max", "upper corner, m"), dim, keyPath(rp, "max"));
  for (int d = 0; d < dim; ++d)
    if (!(s.regionMin[d] < s.regionMax[d]))
      fail(indexPath(keyPath(rp, "max"), size_t(d)), "must be greater than region.min[" + std::to_string(d) + "]");
  const bool hasF = c.contains("frames"), hasS = c.contains("seconds");
  if (hasF && hasS) fail(keyPath(p, "seconds"), "give either frames or seconds, not both");
  if (!hasF && !hasS) fail(keyPath(p, "frames"), "missing (give frames or seconds)");
  if (hasF) {
    s.frames = int(integerField(c, p, "frames", kRequired, {1, 1000000}));
  } else {
    const std::string sp = keyPath(p, "seconds");
    const double v = getNumber(c["seconds"], sp);
    if (!(v > 0) || v > kMaxCaptureSeconds)
      fail(sp, formatNumber(v) + " is outside the allowed range (0, " + formatNumber(kMaxCaptureSeconds) + "] s");
    s.seconds = v;
  }
  if (c.contains("start"))
    s.start = numberField(c, p, "start", kRequired, {0, kMaxCaptureSeconds, "s"});
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

int recipeSimulationFrames(const Recipe& recipe) {
  const double frameRate = recipe.dimension == 2 ? parseScene<2>(recipe.scene).settings.frameRate
                                                 : parseScene<3>(recipe.scene).settings.frameRate;
  int last = 0;
  for (const CaptureSpec& c : recipe.captures) last = std::max(last, windowOf(c, 1.0 / frameRate).last());
  return last;
}

Recipe loadRecipe(const std::string& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw SceneError("", "cannot read recipe '" + file + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  nlohmann::json recipe = parseSceneText(text, file);
  resolveSceneFilePaths(recipe, file);
  return parseRecipe(recipe, text);
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
  prog.simFrames = last;
  auto step = [&]() {
    prog.stats = sim.advanceFrame();
    ++prog.simFrame;
    if (!prog.stats.finite)
      throw std::runtime_error("non-finite position or velocity at simulation frame " +
                               std::to_string(prog.stats.frame) + " (t = " + std::to_string(prog.stats.time) +
                               " s); recording stopped, nothing written");
    if (options.simulationProgress && !options.simulationProgress(prog))
      throw RecordAborted("recording interrupted, nothing written");
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

// The "exists" check of a template about to be written without force.
void checkTemplateAbsent(const std::string& name, const std::string& path, const std::string& forceHint) {
  if (std::filesystem::exists(path))
    throw DatabaseError("template '" + name + "' already exists ('" + path + "'); use " + forceHint +
                        " to overwrite it");
}

void createTemplatesDir(const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw DatabaseError("cannot create template directory '" + dir + "': " + ec.message());
}

// Moves the staged templates to their names (StagedFiles), in the
// database's error types.
void commitTemplates(StagedFiles& staged, const std::string& forceHint) {
  try {
    staged.commit();
  } catch (const PublishError& e) {
    if (e.exists)
      throw DatabaseError("template file '" + e.path + "' was created while recording; use " + forceHint +
                          " to overwrite it");
    throw TemplateError("template file '" + e.path + "': " + e.what());
  }
}

}  // namespace

template <int D>
std::string publishTemplate(const std::string& templatesDir, const Template<D>& tpl, bool force,
                            const std::string& forceHint) {
  const TemplateDatabase db(templatesDir);
  const std::string path = db.pathFor(tpl.header.name);
  recoverPublishing(templatesDir);  // a crashed publish's templates back to their old files before checking
  if (!force) checkTemplateAbsent(tpl.header.name, path, forceHint);
  createTemplatesDir(templatesDir);
  StagedFiles staged(force);
  const std::string tmp = stagingPath(path);
  staged.stage(tmp, path);
  writeTemplate<D>(tmp, tpl);
  commitTemplates(staged, forceHint);
  return path;
}

RecordResult recordRecipe(const Recipe& recipe, const RecordOptions& options) {
  namespace fs = std::filesystem;
  TemplateDatabase db(options.templatesDir);
  recoverPublishing(options.templatesDir);  // a crashed publish's templates back to their old files before checking
  std::vector<std::string> paths;
  for (const CaptureSpec& c : recipe.captures) {
    paths.push_back(db.pathFor(c.name));
    if (!options.force) checkTemplateAbsent(c.name, paths.back(), "--force");
  }
  createTemplatesDir(options.templatesDir);

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
    StagedFiles commit(options.force);
    for (size_t k = 0; k < tpls.size(); ++k) {
      const auto w0 = std::chrono::steady_clock::now();
      const std::string staged = stagingPath(paths[k]);
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
    commitTemplates(commit, "--force");
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
template std::string publishTemplate<2>(const std::string&, const Template<2>&, bool, const std::string&);
template std::string publishTemplate<3>(const std::string&, const Template<3>&, bool, const std::string&);

}  // namespace fc
