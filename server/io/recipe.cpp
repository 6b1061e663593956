#include "io/recipe.h"
#include "io/template_database.h"
#include "io/template_file.h"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
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

CaptureSpec parseCapture(const nlohmann::json& c, int dim) {
  const std::string p = "capture";
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

}  // namespace

Recipe parseRecipe(const nlohmann::json& recipe, const std::string& text) {
  if (!recipe.is_object()) throw SceneError("", "a recipe must be a JSON object (a scene plus \"capture\")");
  Recipe r;
  r.scene = recipe;
  if (!recipe.contains("capture")) throw SceneError("capture", "missing (a recipe is a scene plus a capture object)");
  r.scene.erase("capture");
  r.dimension = sceneDimension(r.scene);
  r.capture = parseCapture(recipe["capture"], r.dimension);
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
Template<D> captureTemplate(const Recipe& recipe, const RecordOptions& options) {
  if (recipe.dimension != D)
    throw std::invalid_argument("recipe is " + std::to_string(recipe.dimension) + "D, capture requested in " +
                                std::to_string(D) + "D");
  const SimulationSetup<D> setup = parseScene<D>(recipe.scene, options.particleRadiusOverride);
  Simulation<D> sim(setup);
  const double frameDt = sim.frameDuration();
  const CaptureSpec& c = recipe.capture;
  const int frames = c.frames ? *c.frames : int(std::lround(*c.seconds / frameDt)) + 1;
  const int startFrames = int(std::lround(c.start / frameDt));

  Template<D> tpl;
  TemplateHeader& h = tpl.header;
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
  AABB<D> region;
  for (int d = 0; d < D; ++d) {
    region.min[d] = Real(c.regionMin[d]);
    region.max[d] = Real(c.regionMax[d]);
  }

  RecordProgress prog;
  prog.frames = frames;
  auto step = [&]() {
    prog.stats = sim.advanceFrame();
    ++prog.simFrame;
    if (!prog.stats.finite)
      throw std::runtime_error("non-finite position or velocity at simulation frame " +
                               std::to_string(prog.stats.frame) + " (t = " + std::to_string(prog.stats.time) +
                               " s); recording stopped, nothing written");
  };
  for (int i = 0; i < startFrames; ++i) step();
  tpl.frames.reserve(size_t(frames));
  for (int f = 0; f < frames; ++f) {
    if (f > 0) step();
    TemplateFrame<D> fr;
    const auto& p = sim.fluid;
    for (size_t i = 0; i < p.size(); ++i) {
      if (p.kind[i] != uint8_t(ParticleKind::Liquid) || !region.contains(p.x[i])) continue;
      fr.x.push_back(p.x[i]);
      fr.v.push_back(p.v[i]);
      fr.mass.push_back(p.mass[i]);
      fr.phase.push_back(p.phase[i]);
    }
    prog.frame = f + 1;
    prog.captured = fr.size();
    tpl.frames.push_back(std::move(fr));
    if (options.progress && !options.progress(prog)) throw RecordAborted("recording interrupted, nothing written");
  }
  return tpl;
}

RecordResult recordRecipe(const Recipe& recipe, const RecordOptions& options) {
  TemplateDatabase db(options.templatesDir);
  const std::string path = db.pathFor(recipe.capture.name);
  if (!options.force && std::filesystem::exists(path))
    throw DatabaseError("template '" + recipe.capture.name + "' already exists ('" + path +
                        "'); use --force to overwrite it");
  std::error_code ec;
  std::filesystem::create_directories(options.templatesDir, ec);
  if (ec) throw DatabaseError("cannot create template directory '" + options.templatesDir + "': " + ec.message());

  RecordResult res;
  res.path = path;
  res.name = recipe.capture.name;
  res.dimension = recipe.dimension;
  auto run = [&](auto dimTag) {
    constexpr int D = decltype(dimTag)::value;
    const auto t0 = std::chrono::steady_clock::now();
    Template<D> tpl = captureTemplate<D>(recipe, options);
    const auto t1 = std::chrono::steady_clock::now();
    for (const auto& f : tpl.frames) {
      res.capturedPerFrame.push_back(f.size());
      res.particleFrames += f.size();
    }
    res.frames = tpl.frames.size();
    // Checked again: the simulation may have taken minutes.
    if (!options.force && std::filesystem::exists(path))
      throw DatabaseError("template '" + recipe.capture.name + "' was created while recording ('" + path +
                          "'); use --force to overwrite it");
    writeTemplate<D>(path, tpl);
    const auto t2 = std::chrono::steady_clock::now();
    res.wallSeconds = std::chrono::duration<double>(t1 - t0).count();
    res.writeSeconds = std::chrono::duration<double>(t2 - t1).count();
    if (options.keepTemplate) {
      if constexpr (D == 2) res.tpl2 = std::move(tpl);
      else res.tpl3 = std::move(tpl);
    }
  };
  if (recipe.dimension == 2) run(std::integral_constant<int, 2>{});
  else run(std::integral_constant<int, 3>{});
  return res;
}

template Template<2> captureTemplate<2>(const Recipe&, const RecordOptions&);
template Template<3> captureTemplate<3>(const Recipe&, const RecordOptions&);

}  // namespace fc
