// Recorder (io/recipe.h) and template database (io/template_database.h):
// record a tiny recipe in-process, load it back through the database, shared
// loading, name validation, remove, missing templates, no silent overwrite;
// recipes with an array of captures (several templates from one simulation,
// written all or nothing).
#include "io/recipe.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include "tests/hdf5_test_util.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <thread>
#include <vector>

namespace fs = std::filesystem;
using namespace fc;
using fc::test::readFile;
using fc::test::TempDir;

namespace {

// 32 particles (r = 0.02) in a small tank; the region holds part of them.
nlohmann::json tinyRecipe(const std::string& name = "tiny", int frames = 12) {
  return nlohmann::json::parse(R"({
    "name": "tiny", "dimension": 2, "particle_radius": 0.02,
    "domain": {"min": [0, 0], "max": [0.6, 0.6]},
    "gravity": [0, -9.81],
    "phases": [{"name": "water", "rest_density": 1000, "viscosity": 0.001}],
    "fluid_blocks": [{"min": [0.04, 0.04], "max": [0.2, 0.36], "phase": "water", "velocity": [0.5, 0]}],
    "solver": {"method": "dfsph"},
    "settings": {"frame_rate": 60},
    "effects": ["viscosity_standard"],
    "capture": {"name": "tiny", "region": {"min": [0, 0], "max": [0.3, 0.25]}, "frames": 12}
  })")
      .patch(nlohmann::json::array({{{"op", "replace"}, {"path", "/capture/name"}, {"value", name}},
                                    {{"op", "replace"}, {"path", "/capture/frames"}, {"value", frames}}}));
}

// Records the one-capture tiny recipe: its single template.
RecordedTemplate recordTiny(const std::string& dir, const std::string& name = "tiny", bool force = false,
                            bool keep = false) {
  const nlohmann::json j = tinyRecipe(name);
  RecordOptions o;
  o.templatesDir = dir;
  o.force = force;
  o.keepTemplate = keep;
  RecordResult r = recordRecipe(parseRecipe(j, j.dump(1)), o);
  EXPECT_EQ(r.templates.size(), 1u);
  return std::move(r.templates.at(0));
}

// The tiny recipe with "capture" replaced by an array of captures.
nlohmann::json tinyArrayRecipe(const nlohmann::json& captures) {
  nlohmann::json j = tinyRecipe();
  j["capture"] = captures;
  return j;
}

nlohmann::json captureOf(const std::string& name, std::vector<double> lo, std::vector<double> hi, int frames,
                         double start = 0) {
  return {{"name", name}, {"region", {{"min", lo}, {"max", hi}}}, {"frames", frames}, {"start", start}};
}

std::string sceneErrorPath(const nlohmann::json& j) {
  try {
    parseRecipe(j);
  } catch (const SceneError& e) {
    return e.path;
  }
  return "<no error>";
}

}  // namespace

TEST(TemplateDatabase, RecordThenLoadRoundTrip) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  const RecordedTemplate res = recordTiny(dir, "tiny", false, true);
  ASSERT_TRUE(res.tpl2.has_value());
  const Template<2>& rec = *res.tpl2;
  EXPECT_EQ(res.path, (fs::path(dir) / "tiny.h5").string());
  EXPECT_TRUE(fs::is_regular_file(res.path));
  ASSERT_EQ(res.frames, 12u);
  ASSERT_EQ(rec.frames.size(), 12u);

  // Captured particles are exactly the liquid inside the region, and the
  // region cuts the block: some frames hold particles, none holds all 32.
  size_t total = 0;
  for (size_t f = 0; f < rec.frames.size(); ++f) {
    EXPECT_EQ(res.capturedPerFrame[f], rec.frames[f].size());
    EXPECT_LT(rec.frames[f].size(), 32u);
    total += rec.frames[f].size();
    for (const auto& x : rec.frames[f].x) EXPECT_TRUE(rec.region().contains(x));
  }
  EXPECT_GT(rec.frames[0].size(), 0u);
  EXPECT_EQ(total, res.particleFrames);

  TemplateDatabase db(dir);
  auto lt = db.load<2>("tiny");
  const Template<2>& got = lt->templ();
  const TemplateHeader& h = got.header;
  EXPECT_EQ(h.name, "tiny");
  EXPECT_EQ(h.dimension, 2);
  EXPECT_DOUBLE_EQ(h.frameRate, 60.0);
  EXPECT_NEAR(h.particleRadius, 0.02, 1e-7);
  EXPECT_NEAR(h.supportRadius, rec.header.supportRadius, 1e-12);
  EXPECT_GT(h.supportRadius, h.particleRadius);
  EXPECT_DOUBLE_EQ(h.restDensity, 1000.0);
  EXPECT_EQ(h.regionMin, (std::vector<double>{0, 0}));
  EXPECT_EQ(h.regionMax, (std::vector<double>{0.3, 0.25}));
  EXPECT_EQ(h.recipe, tinyRecipe().dump(1));
  EXPECT_EQ(h.createdBy, std::string("flowclip ") + FLOWCLIP_VERSION);
  EXPECT_EQ(lt->accel.frameCount(), 12u);
  EXPECT_EQ(lt->accel.particleFrames(), total);
  EXPECT_GT(lt->accel.repulsionParticleFrames(), 0u);  // the layer is built at load
  EXPECT_DOUBLE_EQ(double(lt->accel.supportRadius), double(Real(h.supportRadius)));
  EXPECT_GE(lt->readSeconds, 0.0);
  EXPECT_EQ(lt->buildSeconds, lt->accel.buildSeconds);

  ASSERT_EQ(got.frames.size(), rec.frames.size());
  const double posTol = 0.01 * h.particleRadius * 1.0001 + 1e-9;
  for (size_t f = 0; f < rec.frames.size(); ++f) {
    const auto& a = rec.frames[f];
    const auto& b = got.frames[f];
    ASSERT_EQ(a.size(), b.size()) << "frame " << f;
    double vmax = 0;
    for (const auto& v : a.v) vmax = std::max(vmax, double(v.cwiseAbs().maxCoeff()));
    const double velTol = vmax / 1023.0 * 0.5 * 1.001 + 1e-6 * (1 + vmax);
    // The file orders particles by Morton code: match each recorded particle
    // to its nearest loaded one (particles are ~2r apart, errors 0.01r).
    std::vector<bool> used(b.size(), false);
    for (size_t i = 0; i < a.size(); ++i) {
      size_t best = 0;
      double bestD = std::numeric_limits<double>::max();
      for (size_t k = 0; k < b.size(); ++k) {
        const double d = double((a.x[i] - b.x[k]).norm());
        if (d < bestD) bestD = d, best = k;
      }
      ASSERT_FALSE(used[best]) << "frame " << f << " particle " << i;
      used[best] = true;
      for (int d = 0; d < 2; ++d) {
        EXPECT_LE(std::abs(double(a.x[i][d] - b.x[best][d])), posTol) << "frame " << f;
        EXPECT_LE(std::abs(double(a.v[i][d] - b.v[best][d])), velTol) << "frame " << f;
      }
      EXPECT_EQ(a.mass[i], b.mass[best]);
      EXPECT_EQ(a.phase[i], b.phase[best]);
    }
  }

  const auto entries = db.list();
  ASSERT_EQ(entries.size(), 1u);
  EXPECT_EQ(entries[0].name, "tiny");
  EXPECT_EQ(entries[0].dimension, 2);
  EXPECT_EQ(entries[0].frames, 12u);
  EXPECT_NEAR(entries[0].duration, 11.0 / 60.0, 1e-12);
  EXPECT_NEAR(entries[0].avgParticles, double(total) / 12.0, 1e-9);
  EXPECT_EQ(entries[0].bytesOnDisk, fs::file_size(res.path));
  EXPECT_TRUE(entries[0].error.empty());
}

TEST(TemplateDatabase, SecondsAndStartSetFrameCount) {
  TempDir tmp;
  nlohmann::json j = tinyRecipe();
  j["capture"].erase("frames");
  j["capture"]["seconds"] = 0.1;  // 6 frames at 60 fps, + frame 0
  j["capture"]["start"] = 0.05;
  RecordOptions o;
  o.templatesDir = tmp.file("db");
  int calls = 0, lastSim = 0;
  o.progress = [&](const RecordProgress& p) {
    ++calls;
    lastSim = p.simFrame;
    return true;
  };
  const RecordResult r = recordRecipe(parseRecipe(j), o);
  ASSERT_EQ(r.templates.size(), 1u);
  EXPECT_EQ(r.templates[0].frames, 7u);
  EXPECT_EQ(calls, 7);
  EXPECT_EQ(lastSim, 3 + 6);  // 0.05 s = 3 frames before template frame 0
}

TEST(TemplateDatabase, AbortedRecordingWritesNothing) {
  TempDir tmp;
  RecordOptions o;
  o.templatesDir = tmp.file("db");
  o.progress = [](const RecordProgress& p) { return p.frame < 3; };
  EXPECT_THROW(recordRecipe(parseRecipe(tinyRecipe()), o), RecordAborted);
  EXPECT_FALSE(fs::exists(tmp.file("db/tiny.h5")));
}

TEST(TemplateDatabase, SharedLoadReturnsSamePointer) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  recordTiny(dir);
  TemplateDatabase db(dir);
  auto a = db.load<2>("tiny");
  auto b = db.load<2>("tiny");
  EXPECT_EQ(a.get(), b.get());
  EXPECT_EQ(a->accel.source, a->tpl.get());

  // Concurrent loads while one is held: all the same object.
  std::vector<std::shared_ptr<const LoadedTemplate<2>>> got(8);
  std::vector<std::thread> threads;
  for (size_t i = 0; i < got.size(); ++i) threads.emplace_back([&, i] { got[i] = db.load<2>("tiny"); });
  for (auto& t : threads) t.join();
  for (const auto& p : got) EXPECT_EQ(p.get(), a.get());

  // Concurrent first loads (nothing held) share one result too.
  a.reset(), b.reset(), got.assign(got.size(), nullptr);
  TemplateDatabase db2(dir);
  threads.clear();
  for (size_t i = 0; i < got.size(); ++i) threads.emplace_back([&, i] { got[i] = db2.load<2>("tiny"); });
  for (auto& t : threads) t.join();
  for (const auto& p : got) EXPECT_EQ(p.get(), got[0].get());

  // A different database object (another cache) loads its own copy.
  TemplateDatabase other(dir);
  EXPECT_NE(other.load<2>("tiny").get(), got[0].get());

  // Re-recording (--force) replaces the file: the next load is fresh, the
  // holder keeps the old one.
  const auto held = db2.load<2>("tiny");
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  recordTiny(dir, "tiny", true);
  const auto fresh = db2.load<2>("tiny");
  EXPECT_NE(fresh.get(), held.get());
  EXPECT_EQ(held->templ().frames.size(), 12u);
}

TEST(TemplateDatabase, DimensionMismatchIsAClearError) {
  TempDir tmp;
  recordTiny(tmp.file("db"));
  TemplateDatabase db(tmp.file("db"));
  try {
    db.load<3>("tiny");
    FAIL() << "loaded a 2D template as 3D";
  } catch (const TemplateError& e) {
    EXPECT_NE(std::string(e.what()).find("2D template"), std::string::npos) << e.what();
  }
}

TEST(TemplateDatabase, NameValidation) {
  EXPECT_TRUE(isValidTemplateName("drop2d"));
  EXPECT_TRUE(isValidTemplateName("A-b_9"));
  EXPECT_TRUE(isValidTemplateName(std::string(64, 'a')));
  TempDir tmp;
  const std::string dir = tmp.file("db");
  fs::create_directories(dir);
  // A file next to the database that "../x" would reach.
  std::ofstream(tmp.file("x.h5")) << "outside";
  std::ofstream(tmp.file("db/a")) << "";
  TemplateDatabase db(dir);
  for (const std::string& bad : std::vector<std::string>{"../x", "a/b", "", std::string(65, 'a'), "..", ".", "a.b", "x y", "/etc/passwd",
                                std::string("a\0b", 3), "é"}) {
    EXPECT_FALSE(isValidTemplateName(bad)) << bad;
    EXPECT_THROW(db.pathFor(bad), DatabaseError) << bad;
    EXPECT_THROW(db.contains(bad), DatabaseError) << bad;
    EXPECT_THROW(db.load<2>(bad), DatabaseError) << bad;
    EXPECT_THROW(db.remove(bad), DatabaseError) << bad;
    EXPECT_THROW(db.entry(bad), DatabaseError) << bad;
  }
  try {
    db.remove("../x");
  } catch (const DatabaseError& e) {
    EXPECT_NE(std::string(e.what()).find("invalid template name"), std::string::npos) << e.what();
  }
  EXPECT_EQ(readFile(tmp.file("x.h5")), "outside");
  // The recorder refuses a bad capture name before simulating.
  nlohmann::json j = tinyRecipe();
  j["capture"]["name"] = "../x";
  EXPECT_EQ(sceneErrorPath(j), "capture.name");
  EXPECT_EQ(readFile(tmp.file("x.h5")), "outside");
}

TEST(TemplateDatabase, RemoveDeletesOnlyThatFile) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  recordTiny(dir, "one");
  recordTiny(dir, "two");
  std::ofstream(tmp.file("db/notes.txt")) << "keep";
  std::ofstream(tmp.file("one.h5")) << "outside";
  TemplateDatabase db(dir);
  auto held = db.load<2>("one");
  ASSERT_EQ(db.list().size(), 2u);
  db.remove("one");
  EXPECT_FALSE(fs::exists(tmp.file("db/one.h5")));
  EXPECT_TRUE(fs::exists(tmp.file("db/two.h5")));
  EXPECT_EQ(readFile(tmp.file("db/notes.txt")), "keep");
  EXPECT_EQ(readFile(tmp.file("one.h5")), "outside");
  const auto entries = db.list();
  ASSERT_EQ(entries.size(), 1u);
  EXPECT_EQ(entries[0].name, "two");
  EXPECT_EQ(held->templ().frames.size(), 12u);  // the holder keeps its copy
  EXPECT_THROW(db.load<2>("one"), DatabaseError);
  EXPECT_THROW(db.remove("one"), DatabaseError);
}

TEST(TemplateDatabase, MissingTemplateIsAClearError) {
  TempDir tmp;
  TemplateDatabase db(tmp.file("nowhere"));
  EXPECT_TRUE(db.list().empty());
  EXPECT_FALSE(db.contains("ghost"));
  try {
    db.load<2>("ghost");
    FAIL();
  } catch (const DatabaseError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("no template 'ghost'"), std::string::npos) << m;
  }
  EXPECT_THROW(db.entry("ghost"), DatabaseError);
  EXPECT_FALSE(fs::exists(tmp.file("nowhere")));
}

TEST(TemplateDatabase, UnreadableFileIsListedWithError) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  recordTiny(dir);
  std::ofstream(tmp.file("db/broken.h5")) << "not hdf5";
  TemplateDatabase db(dir);
  const auto entries = db.list();
  ASSERT_EQ(entries.size(), 2u);
  EXPECT_EQ(entries[0].name, "broken");
  EXPECT_FALSE(entries[0].error.empty());
  EXPECT_TRUE(entries[1].error.empty());
  EXPECT_THROW(db.load<2>("broken"), TemplateError);
}

TEST(TemplateDatabase, RecordingOntoExistingNameNeedsForce) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  recordTiny(dir);
  const std::string path = tmp.file("db/tiny.h5");
  const std::string before = readFile(path);
  const auto mtime = fs::last_write_time(path);
  try {
    recordTiny(dir);
    FAIL() << "overwrote without force";
  } catch (const DatabaseError& e) {
    EXPECT_NE(std::string(e.what()).find("already exists"), std::string::npos) << e.what();
  }
  EXPECT_EQ(readFile(path), before);
  EXPECT_EQ(fs::last_write_time(path), mtime);
  // Nothing else left behind (no temporary file).
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
  // With force it is replaced.
  const RecordedTemplate r = recordTiny(dir, "tiny", true);
  EXPECT_EQ(r.frames, 12u);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
}

TEST(Recipe, ValidationNamesKeyPaths) {
  nlohmann::json j = tinyRecipe();
  j.erase("capture");
  EXPECT_EQ(sceneErrorPath(j), "capture");
  j = tinyRecipe();
  j["capture"]["region"]["min"] = {0, "a"};
  EXPECT_EQ(sceneErrorPath(j), "capture.region.min[1]");
  j = tinyRecipe();
  j["capture"]["region"]["max"] = {0.3, 0.25, 1};
  EXPECT_EQ(sceneErrorPath(j), "capture.region.max");
  j = tinyRecipe();
  j["capture"]["region"]["max"][0] = -1;
  EXPECT_EQ(sceneErrorPath(j), "capture.region.max[0]");
  j = tinyRecipe();
  j["capture"]["seconds"] = 1;
  EXPECT_EQ(sceneErrorPath(j), "capture.seconds");
  j = tinyRecipe();
  j["capture"].erase("frames");
  EXPECT_EQ(sceneErrorPath(j), "capture.frames");
  j = tinyRecipe();
  j["capture"]["frames"] = 0;
  EXPECT_EQ(sceneErrorPath(j), "capture.frames");
  j = tinyRecipe();
  j["capture"]["frames"] = 2.5;
  EXPECT_EQ(sceneErrorPath(j), "capture.frames");
  j = tinyRecipe();
  j["capture"]["start"] = -1;
  EXPECT_EQ(sceneErrorPath(j), "capture.start");
  j = tinyRecipe();
  j["capture"]["colour"] = 1;
  EXPECT_EQ(sceneErrorPath(j), "capture.colour");
  j = tinyRecipe();
  j["capture"].erase("name");
  EXPECT_EQ(sceneErrorPath(j), "capture.name");
  j = tinyRecipe();
  j["capture"] = 3;
  EXPECT_EQ(sceneErrorPath(j), "capture");
  // Scene errors keep the scene parser's key paths.
  j = tinyRecipe();
  j["fluid_blocks"][0]["min"][0] = -5;
  EXPECT_EQ(sceneErrorPath(j).rfind("fluid_blocks[0]", 0), 0u) << sceneErrorPath(j);
  EXPECT_EQ(sceneErrorPath(tinyRecipe()), "<no error>");
}

TEST(Recipe, ShippedRecipesParse) {
  const fs::path dir = fs::path(FLOWCLIP_SOURCE_DIR) / "templates" / "recipes";
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".json") continue;
    const Recipe r = loadRecipe(e.path().string());
    ASSERT_FALSE(r.captures.empty()) << e.path();
    // A one-template recipe is named after its template.
    if (r.captures.size() == 1) {
      EXPECT_EQ(r.captures[0].name, e.path().stem().string());
    }
    EXPECT_FALSE(r.text.empty());
    for (const auto& c : r.captures) names.push_back(c.name);
  }
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"blade2d", "blade3d", "column2d", "doubledam2d", "drop2d", "hand3d", "honey3d", "jet2d", "letter_A",
                                      "letter_C", "letter_S", "waterjet2d", "wave2d"}));
}

// Array form: key paths carry the capture's index.
TEST(Recipe, CaptureArrayValidationNamesKeyPaths) {
  const nlohmann::json a = captureOf("a", {0, 0}, {0.3, 0.25}, 4);
  const nlohmann::json b = captureOf("b", {0.2, 0}, {0.6, 0.6}, 4);
  const nlohmann::json c = captureOf("c", {0, 0}, {0.6, 0.1}, 4);
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, b, c})), "<no error>");
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a})), "<no error>");

  // Duplicate names: the later capture's name is the error.
  nlohmann::json dup = b;
  dup["name"] = "a";
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, dup})), "capture[1].name");
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, b, dup})), "capture[2].name");
  try {
    parseRecipe(tinyArrayRecipe({a, dup}));
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("duplicate template name 'a'"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("capture[0].name"), std::string::npos) << e.what();
  }

  nlohmann::json bad = c;
  bad["region"]["min"] = {0, "x"};
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, b, bad})), "capture[2].region.min[1]");
  bad = c;
  bad["region"]["max"][0] = -1;
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, bad})), "capture[1].region.max[0]");
  bad = a;
  bad["colour"] = 1;
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({bad, b})), "capture[0].colour");
  bad = b;
  bad.erase("frames");
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, bad})), "capture[1].frames");
  bad = b;
  bad["start"] = -1;
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, bad})), "capture[1].start");
  bad = b;
  bad["name"] = "../x";
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, bad})), "capture[1].name");
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe({a, 3})), "capture[1]");
  EXPECT_EQ(sceneErrorPath(tinyArrayRecipe(nlohmann::json::array())), "capture");
}

// Two captures of one simulation: each template's frames hold exactly the
// liquid inside its region at its own frames. A third capture of the whole
// domain records every particle of the same simulation: the reference.
TEST(Recipe, CaptureArrayRecordsEachRegion) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  // "left" cuts the block from frame 0; "late" starts 3 frames later
  // (0.05 s at 60 fps) with 7 frames (seconds 0.1) in another box.
  nlohmann::json late = captureOf("late", {0.1, 0}, {0.6, 0.2}, 1, 0.05);
  late.erase("frames");
  late["seconds"] = 0.1;
  const nlohmann::json j = tinyArrayRecipe({captureOf("left", {0, 0}, {0.3, 0.25}, 12), late,
                                            captureOf("all", {0, 0}, {0.6, 0.6}, 12)});
  const Recipe recipe = parseRecipe(j, j.dump(1));
  ASSERT_EQ(recipe.captures.size(), 3u);
  RecordOptions o;
  o.templatesDir = dir;
  o.keepTemplate = true;
  std::vector<size_t> captured;
  int frames = 0;
  o.progress = [&](const RecordProgress& p) {
    captured.push_back(p.captured);
    frames = p.frames;
    EXPECT_EQ(p.frame, int(captured.size()));
    return true;
  };
  const RecordResult res = recordRecipe(recipe, o);
  ASSERT_EQ(res.templates.size(), 3u);
  EXPECT_EQ(res.dimension, 2);
  EXPECT_EQ(frames, 12);  // capture frames 0..11 (late: 3..9)
  ASSERT_EQ(captured.size(), 12u);

  const RecordedTemplate& left = res.templates[0];
  const RecordedTemplate& lateT = res.templates[1];
  const RecordedTemplate& all = res.templates[2];
  EXPECT_EQ(left.name, "left");
  EXPECT_EQ(lateT.name, "late");
  EXPECT_EQ(left.path, (fs::path(dir) / "left.h5").string());
  EXPECT_EQ(lateT.path, (fs::path(dir) / "late.h5").string());
  ASSERT_EQ(left.frames, 12u);
  ASSERT_EQ(lateT.frames, 7u);
  ASSERT_EQ(all.frames, 12u);
  ASSERT_TRUE(left.tpl2 && lateT.tpl2 && all.tpl2);

  // The particles of `ref` inside `box`, in order.
  auto inside = [](const TemplateFrame<2>& ref, const AABB<2>& box) {
    std::vector<Vec<2>> x;
    for (const auto& p : ref.x)
      if (box.contains(p)) x.push_back(p);
    return x;
  };
  const AABB<2> leftBox = left.tpl2->region(), lateBox = lateT.tpl2->region();
  size_t leftSome = 0, lateSome = 0;
  for (size_t f = 0; f < 12; ++f) {
    const TemplateFrame<2>& ref = all.tpl2->frames[f];
    ASSERT_EQ(ref.size(), 32u) << "frame " << f;  // the whole liquid
    const auto want = inside(ref, leftBox);
    const auto& got = left.tpl2->frames[f];
    ASSERT_EQ(got.size(), want.size()) << "frame " << f;
    for (size_t i = 0; i < want.size(); ++i) EXPECT_EQ(got.x[i], want[i]) << "frame " << f;
    EXPECT_LT(got.size(), 32u);
    leftSome += !got.x.empty();
    size_t sum = ref.size() + got.size();
    if (f >= 3 && f <= 9) {
      const auto wantLate = inside(ref, lateBox);
      const auto& gotLate = lateT.tpl2->frames[f - 3];
      ASSERT_EQ(gotLate.size(), wantLate.size()) << "frame " << f;
      for (size_t i = 0; i < wantLate.size(); ++i) EXPECT_EQ(gotLate.x[i], wantLate[i]) << "frame " << f;
      EXPECT_LT(gotLate.size(), 32u);
      lateSome += !gotLate.x.empty();
      sum += gotLate.size();
    }
    EXPECT_EQ(captured[f], sum) << "frame " << f;
  }
  EXPECT_GT(leftSome, 0u);
  EXPECT_GT(lateSome, 0u);

  // On disk: three templates with their own names, regions and frames, the
  // same recipe text.
  TemplateDatabase db(dir);
  const auto entries = db.list();
  ASSERT_EQ(entries.size(), 3u);
  for (const RecordedTemplate* t : {&left, &lateT, &all}) {
    auto lt = db.load<2>(t->name);
    const Template<2>& got = lt->templ();
    EXPECT_EQ(got.header.name, t->name);
    EXPECT_EQ(got.header.regionMin, t->tpl2->header.regionMin);
    EXPECT_EQ(got.header.regionMax, t->tpl2->header.regionMax);
    EXPECT_EQ(got.header.recipe, j.dump(1));
    ASSERT_EQ(got.frames.size(), t->frames);
    for (size_t f = 0; f < t->frames; ++f) {
      EXPECT_EQ(got.frames[f].size(), t->capturedPerFrame[f]);
      for (const auto& x : got.frames[f].x)
        for (int d = 0; d < 2; ++d) {
          EXPECT_GE(double(x[d]), got.header.regionMin[d] - 0.01 * got.header.particleRadius - 1e-6);
          EXPECT_LE(double(x[d]), got.header.regionMax[d] + 0.01 * got.header.particleRadius + 1e-6);
        }
    }
  }
  EXPECT_EQ(tmp.entries(), std::vector<std::string>{"db"});
  std::vector<std::string> files;
  for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path().filename().string());
  std::sort(files.begin(), files.end());
  EXPECT_EQ(files, (std::vector<std::string>{"all.h5", "late.h5", "left.h5"}));  // no temporary left
}

namespace {
std::vector<std::string> filesIn(const std::string& dir) {
  std::vector<std::string> files;
  for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path().filename().string());
  std::sort(files.begin(), files.end());
  return files;
}
}  // namespace

// All or nothing: an existing template stops the recording before it starts;
// an interruption or a failure while moving the files into place leaves no
// new file and restores what --force replaced.
TEST(Recipe, CaptureArrayWritesAllOrNothing) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  fs::create_directories(dir);
  const nlohmann::json j =
      tinyArrayRecipe({captureOf("a", {0, 0}, {0.3, 0.25}, 6), captureOf("b", {0, 0}, {0.6, 0.6}, 6)});
  const Recipe recipe = parseRecipe(j);
  RecordOptions o;
  o.templatesDir = dir;

  // "b" exists: nothing simulated, nothing written, "b" untouched.
  std::ofstream(tmp.file("db/b.h5")) << "old b";
  int calls = 0;
  o.progress = [&](const RecordProgress&) { return ++calls > 0; };
  try {
    recordRecipe(recipe, o);
    FAIL() << "overwrote without force";
  } catch (const DatabaseError& e) {
    EXPECT_NE(std::string(e.what()).find("template 'b' already exists"), std::string::npos) << e.what();
  }
  EXPECT_EQ(calls, 0);
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"b.h5"});
  EXPECT_EQ(readFile(tmp.file("db/b.h5")), "old b");

  // "b" appears while recording: no file written, the newcomer untouched.
  fs::remove(tmp.file("db/b.h5"));
  o.progress = [&](const RecordProgress& p) {
    if (p.frame == 2) std::ofstream(tmp.file("db/b.h5")) << "new b";
    return true;
  };
  EXPECT_THROW(recordRecipe(recipe, o), DatabaseError);
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"b.h5"});
  EXPECT_EQ(readFile(tmp.file("db/b.h5")), "new b");
  fs::remove(tmp.file("db/b.h5"));

  // Interrupted: nothing written.
  o.progress = [](const RecordProgress& p) { return p.frame < 3; };
  EXPECT_THROW(recordRecipe(recipe, o), RecordAborted);
  EXPECT_TRUE(filesIn(dir).empty());

  // With --force, "a" exists and "b" cannot be replaced (a directory holds
  // its name): the recording fails, "a" is put back, nothing else is left.
  o.progress = nullptr;
  o.force = true;
  std::ofstream(tmp.file("db/a.h5")) << "old a";
  fs::create_directories(tmp.file("db/b.h5"));
  std::ofstream(tmp.file("db/b.h5/x")) << "x";
  EXPECT_THROW(recordRecipe(recipe, o), std::exception);
  EXPECT_EQ(filesIn(dir), (std::vector<std::string>{"a.h5", "b.h5"}));
  EXPECT_EQ(readFile(tmp.file("db/a.h5")), "old a");
  EXPECT_TRUE(fs::is_directory(tmp.file("db/b.h5")));
  // The same without an "a" before: no "a" after.
  fs::remove(tmp.file("db/a.h5"));
  EXPECT_THROW(recordRecipe(recipe, o), std::exception);
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"b.h5"});

  // Once "b" is free, both are written, and --force replaces both.
  fs::remove_all(tmp.file("db/b.h5"));
  std::ofstream(tmp.file("db/a.h5")) << "old a";
  const RecordResult r = recordRecipe(recipe, o);
  ASSERT_EQ(r.templates.size(), 2u);
  EXPECT_EQ(filesIn(dir), (std::vector<std::string>{"a.h5", "b.h5"}));
  TemplateDatabase db(dir);
  EXPECT_EQ(db.load<2>("a")->templ().frames.size(), 6u);
  EXPECT_EQ(db.load<2>("b")->templ().frames.size(), 6u);
  o.force = false;
  EXPECT_THROW(recordRecipe(recipe, o), DatabaseError);
  EXPECT_EQ(filesIn(dir), (std::vector<std::string>{"a.h5", "b.h5"}));
}
