// A session's history leaving the session: the HDF5 + XDMF export
// (Session::exportHistory, service/history_export.h) read back with the HDF5
// C API, and templates recorded from a region of the history
// (Session::recordTemplate) loaded back through the database. Both publish
// atomically: every failure leaves the directory as it was.
#include "service/history_export.h"
#include "service/session.h"

#include "io/staged_files.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include "tests/hdf5_test_util.h"

#include <gtest/gtest.h>
#include <hdf5.h>
#include <omp.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

namespace fc::service {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using fc::test::readFile;
using fc::test::TempDir;
using namespace std::chrono_literals;

constexpr auto kWait = 4000ms;

// 100 particles (a 10 × 10 block) falling in a 1 m tank.
json smallScene() {
  return json::parse(R"({
    "name": "tank", "dimension": 2, "particle_radius": 0.02,
    "domain": {"min": [0, 0], "max": [1, 1]},
    "fluid_blocks": [{"min": [0, 0.3], "max": [0.4, 0.7]}]
  })");
}

struct Fixture {
  TempDir tmp;
  TemplateDatabase db{tmp.file("templates")};
  std::unique_ptr<Session> session;
  explicit Fixture(int frames = 6) {
    fs::create_directories(db.directory());
    session = createSession("s1", "", smallScene(), db);
    session->step(frames);
    EXPECT_TRUE(session->waitIdle(kWait));
  }
};

// ---- reading HDF5 back -------------------------------------------------------

struct H5 {
  hid_t id;
  herr_t (*close)(hid_t);
  ~H5() {
    if (id >= 0) close(id);
  }
};

template <class T>
std::vector<T> readAll(hid_t file, const char* name, hid_t fileType, hid_t memType) {
  H5 ds{H5Dopen2(file, name, H5P_DEFAULT), H5Dclose};
  EXPECT_GE(ds.id, 0) << name;
  if (ds.id < 0) return {};
  H5 type{H5Dget_type(ds.id), H5Tclose};
  EXPECT_GT(H5Tequal(type.id, fileType), 0) << name << " has the wrong stored type";
  H5 space{H5Dget_space(ds.id), H5Sclose};
  std::vector<T> out(size_t(H5Sget_simple_extent_npoints(space.id)));
  if (!out.empty()) {
    EXPECT_GE(H5Dread(ds.id, memType, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()), 0) << name;
  }
  return out;
}

std::vector<hsize_t> shapeOf(hid_t file, const char* name) {
  H5 ds{H5Dopen2(file, name, H5P_DEFAULT), H5Dclose};
  if (ds.id < 0) return {};
  H5 space{H5Dget_space(ds.id), H5Sclose};
  std::vector<hsize_t> dims(size_t(H5Sget_simple_extent_ndims(space.id)));
  H5Sget_simple_extent_dims(space.id, dims.data(), nullptr);
  return dims;
}

template <class T>
std::vector<T> readAttr(hid_t file, const char* name, hid_t memType) {
  H5 a{H5Aopen(file, name, H5P_DEFAULT), H5Aclose};
  EXPECT_GE(a.id, 0) << name;
  if (a.id < 0) return {};
  H5 space{H5Aget_space(a.id), H5Sclose};
  std::vector<T> out(size_t(H5Sget_simple_extent_npoints(space.id)));
  EXPECT_GE(H5Aread(a.id, memType, out.data()), 0) << name;
  return out;
}

std::vector<std::string> readStrings(hid_t file, const char* name) {
  H5 a{H5Aopen(file, name, H5P_DEFAULT), H5Aclose};
  EXPECT_GE(a.id, 0) << name;
  if (a.id < 0) return {};
  H5 type{H5Aget_type(a.id), H5Tclose};
  H5 space{H5Aget_space(a.id), H5Sclose};
  std::vector<char*> raw(size_t(H5Sget_simple_extent_npoints(space.id)));
  EXPECT_GE(H5Aread(a.id, type.id, raw.data()), 0) << name;
  std::vector<std::string> out(raw.begin(), raw.end());
  H5Dvlen_reclaim(type.id, space.id, H5P_DEFAULT, raw.data());
  return out;
}

size_t occurrences(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

// ---- export ------------------------------------------------------------------

TEST(SessionHistoryExport, WritesTheFramesAndAnXdmfSidecar) {
  Fixture fx;
  const std::string h5 = fx.tmp.file("hist.h5");
  const HistoryExport e = fx.session->exportHistory(h5, 2, 5);
  EXPECT_EQ(e.h5Path, h5);
  EXPECT_EQ(e.xdmfPath, fx.tmp.file("hist.xdmf"));
  EXPECT_EQ(e.frames, 4);
  EXPECT_EQ(e.particleRows, 400u);
  EXPECT_EQ(e.bytes, fs::file_size(h5) + fs::file_size(e.xdmfPath));
  EXPECT_EQ(fx.tmp.entries(), (std::vector<std::string>{"hist.h5", "hist.xdmf", "templates"}));

  ASSERT_GT(H5Fis_hdf5(h5.c_str()), 0);
  H5 file{H5Fopen(h5.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose};
  ASSERT_GE(file.id, 0);
  const hid_t f = file.id;
  EXPECT_EQ(readStrings(f, "format"), std::vector<std::string>{"flowclip-frames"});
  EXPECT_EQ(readAttr<int>(f, "format_version", H5T_NATIVE_INT), std::vector<int>{1});
  EXPECT_EQ(readAttr<int>(f, "dimension", H5T_NATIVE_INT), std::vector<int>{2});
  EXPECT_EQ(readStrings(f, "scene"), std::vector<std::string>{"tank"});
  EXPECT_EQ(readStrings(f, "source"), std::vector<std::string>{"session replay history (16-bit quantized)"});
  EXPECT_EQ(readStrings(f, "created_by"),
            std::vector<std::string>{std::string("flowclip ") + FLOWCLIP_VERSION + " session s1"});
  EXPECT_EQ(readStrings(f, "phase_names"), std::vector<std::string>{"water"});
  EXPECT_EQ(readAttr<double>(f, "phase_rest_density", H5T_NATIVE_DOUBLE), std::vector<double>{1000});
  EXPECT_EQ(readAttr<double>(f, "particle_radius", H5T_NATIVE_DOUBLE), std::vector<double>{double(Real(0.02))});
  EXPECT_EQ(readAttr<double>(f, "frame_rate", H5T_NATIVE_DOUBLE), std::vector<double>{60});
  EXPECT_EQ(readAttr<double>(f, "domain_min", H5T_NATIVE_DOUBLE), (std::vector<double>{0, 0}));
  EXPECT_EQ(readAttr<double>(f, "domain_max", H5T_NATIVE_DOUBLE), (std::vector<double>{1, 1}));

  EXPECT_EQ(readAll<uint32_t>(f, "/frames/index", H5T_STD_U32LE, H5T_NATIVE_UINT32),
            (std::vector<uint32_t>{2, 3, 4, 5}));
  EXPECT_EQ(readAll<uint64_t>(f, "/frames/offset", H5T_STD_U64LE, H5T_NATIVE_UINT64),
            (std::vector<uint64_t>{0, 100, 200, 300, 400}));
  EXPECT_EQ(readAll<uint32_t>(f, "/frames/count", H5T_STD_U32LE, H5T_NATIVE_UINT32),
            (std::vector<uint32_t>{100, 100, 100, 100}));
  const auto times = readAll<double>(f, "/frames/time", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE);
  ASSERT_EQ(times.size(), 4u);
  EXPECT_EQ(shapeOf(f, "/particles/position"), (std::vector<hsize_t>{400, 2}));
  EXPECT_EQ(shapeOf(f, "/particles/velocity"), (std::vector<hsize_t>{400, 2}));
  const auto pos = readAll<float>(f, "/particles/position", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT);
  const auto vel = readAll<float>(f, "/particles/velocity", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT);
  const auto phase = readAll<uint8_t>(f, "/particles/phase", H5T_STD_U8LE, H5T_NATIVE_UINT8);
  const auto kind = readAll<uint8_t>(f, "/particles/kind", H5T_STD_U8LE, H5T_NATIVE_UINT8);
  ASSERT_EQ(pos.size(), 800u);
  ASSERT_EQ(vel.size(), 800u);
  ASSERT_EQ(phase.size(), 400u);
  ASSERT_EQ(kind.size(), 400u);
  // The history does not hold these: not in the file.
  for (const char* missing : {"/particles/density", "/particles/pressure", "/particles/id"})
    EXPECT_LE(H5Lexists(f, missing, H5P_DEFAULT), 0) << missing;

  double vmax = 0;
  for (int k = 0; k < 4; ++k) {
    const FramePtr snap = fx.session->frame(2 + k);
    ASSERT_TRUE(snap);
    EXPECT_EQ(times[size_t(k)], snap->time);
    for (size_t i = 0; i < 100; ++i) {
      const size_t row = size_t(k) * 100 + i;
      for (int d = 0; d < 2; ++d) {
        // The snapshot's dequantized values, in float32.
        EXPECT_NEAR(pos[row * 2 + size_t(d)], snap->position(i, d), 1e-6);
        EXPECT_NEAR(vel[row * 2 + size_t(d)], snap->velocity(i, d), 1e-6 * (1 + snap->velocityMax[size_t(d)]));
        vmax = std::max(vmax, std::abs(double(vel[row * 2 + size_t(d)])));
      }
      EXPECT_EQ(phase[row], snap->phase[i]);
      EXPECT_EQ(kind[row], snap->kind[i]);
    }
  }
  EXPECT_GT(vmax, 0.05);  // the block is falling

  // The sidecar: one Polyvertex grid per frame, HyperSlabs of the datasets.
  const std::string x = readFile(e.xdmfPath);
  EXPECT_NE(x.find("<Xdmf Version=\"2.0\">"), std::string::npos);
  EXPECT_NE(x.find("CollectionType=\"Temporal\""), std::string::npos);
  EXPECT_EQ(occurrences(x, "<Grid Name=\"frame_"), 4u);
  EXPECT_EQ(occurrences(x, "TopologyType=\"Polyvertex\" NumberOfElements=\"100\""), 4u);
  EXPECT_EQ(occurrences(x, "GeometryType=\"XY\""), 4u);
  EXPECT_EQ(occurrences(x, ">hist.h5:/particles/position</DataItem>"), 4u);
  EXPECT_EQ(occurrences(x, ">hist.h5:/particles/velocity</DataItem>"), 4u);
  EXPECT_EQ(occurrences(x, ">hist.h5:/particles/phase</DataItem>"), 4u);
  EXPECT_EQ(occurrences(x, ">hist.h5:/particles/kind</DataItem>"), 4u);
  EXPECT_EQ(occurrences(x, "Dimensions=\"400 2\" NumberType=\"Float\" Precision=\"4\" Format=\"HDF\""), 8u);
  EXPECT_EQ(occurrences(x, "Dimensions=\"400\" NumberType=\"UChar\" Precision=\"1\" Format=\"HDF\""), 8u);
  // Frame 4 (the third) is rows 200..299: start, stride, count.
  EXPECT_NE(x.find("<Grid Name=\"frame_4\""), std::string::npos);
  EXPECT_EQ(occurrences(x, ">200 0 1 1 100 2</DataItem>"), 2u);
  EXPECT_EQ(occurrences(x, ">200 1 100</DataItem>"), 2u);
  EXPECT_EQ(occurrences(x, "AttributeType=\"Vector\""), 4u);
}

TEST(SessionHistoryExport, DefaultRangeIsTheWholeHistoryAndReplacesFiles) {
  Fixture fx;
  const std::string h5 = fx.tmp.file("all.h5");
  {
    std::ofstream(h5) << "old";
    std::ofstream(fx.tmp.file("all.xdmf")) << "old";
  }
  const HistoryExport e = fx.session->exportHistory(h5);
  EXPECT_EQ(e.frames, 7);  // frames 0..6
  EXPECT_EQ(e.particleRows, 700u);
  EXPECT_GT(H5Fis_hdf5(h5.c_str()), 0);
  EXPECT_EQ(occurrences(readFile(e.xdmfPath), "<Grid Name=\"frame_"), 7u);
  // Open ends: frames of the range that are not kept are skipped.
  EXPECT_EQ(fx.session->exportHistory(h5, 4).frames, 3);
  EXPECT_EQ(fx.session->exportHistory(h5, -1, 1).frames, 2);
  EXPECT_EQ(fx.session->exportHistory(h5, 5, 100).frames, 2);
  EXPECT_EQ(fx.tmp.entries(), (std::vector<std::string>{"all.h5", "all.xdmf", "templates"}));
}

TEST(SessionHistoryExport, FailuresLeaveNoFileAndKeepExistingOnes) {
  Fixture fx(3);
  // Ranges holding no recorded frame.
  EXPECT_THROW(fx.session->exportHistory(fx.tmp.file("a.h5"), 3, 2), std::invalid_argument);
  try {
    fx.session->exportHistory(fx.tmp.file("a.h5"), 10, 20);
    ADD_FAILURE() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("no recorded frame in frames 10 to 20"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("frames 0 to 3 are kept"), std::string::npos) << e.what();
  }
  // A directory that does not exist: the error names the path.
  const std::string missing = fx.tmp.file("nowhere/x.h5");
  try {
    fx.session->exportHistory(missing);
    ADD_FAILURE() << "expected std::runtime_error";
  } catch (const std::invalid_argument& e) {
    ADD_FAILURE() << e.what();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
  }
  EXPECT_EQ(fx.tmp.entries(), std::vector<std::string>{"templates"});
  // The sidecar cannot be published (its name is a directory): the HDF5 file
  // already moved in place is taken back and the old one restored.
  const std::string h5 = fx.tmp.file("keep.h5");
  std::ofstream(h5) << "old";
  fs::create_directory(fx.tmp.file("keep.xdmf"));
  try {
    fx.session->exportHistory(h5);
    ADD_FAILURE() << "expected std::runtime_error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(h5), std::string::npos) << e.what();
  }
  EXPECT_EQ(readFile(h5), "old");
  EXPECT_TRUE(fs::is_directory(fx.tmp.file("keep.xdmf")));
  EXPECT_EQ(fx.tmp.entries(), (std::vector<std::string>{"keep.h5", "keep.xdmf", "templates"}));
}

// Killed at each crash point of publishing in turn (a forked child), then
// recovered: both files old or both new, nothing else in the directory.
TEST(SessionHistoryExport, KilledAtAnyStepLeavesBothFilesOldOrBothNew) {
  Fixture fx(2);
  const std::vector<FramePtr> frames = fx.session->history();
  ExportHeader h;
  h.sceneName = "tank";
  h.dimension = 2;
  h.particleRadius = 0.02;
  h.frameRate = 60;
  h.phases = {Phase{}};
  h.domainMin = {0, 0};
  h.domainMax = {1, 1};
  h.createdBy = "test";
  const std::string dir = fx.tmp.file("exports"), h5 = dir + "/e.h5", xdmf = dir + "/e.xdmf";
  // Both files exist, or only the sidecar (the other was deleted by hand).
  for (const bool withH5 : {true, false}) {
    int olds = 0, news = 0;
    for (int k = 1;; ++k) {
      ASSERT_LT(k, 50) << "the export never finished";
      fs::remove_all(dir);
      fs::create_directories(dir);
      if (withH5) std::ofstream(h5) << "old h5";
      std::ofstream(xdmf) << "old xdmf";
      std::fflush(nullptr);
      const pid_t pid = ::fork();
      if (pid == 0) {
        ::alarm(20);            // a hang fails the test instead of blocking it
        omp_set_num_threads(1);  // the parent's OpenMP threads do not exist here
        StagedFiles::testCrashAfter(k);
        try {
          writeHistoryExport(h5, frames, h);
        } catch (...) {
          ::_exit(3);
        }
        ::_exit(0);
      }
      int status = 0;
      ::waitpid(pid, &status, 0);
      ASSERT_TRUE(WIFEXITED(status)) << "step " << k << ": signal " << WTERMSIG(status);
      const int code = WEXITSTATUS(status);
      ASSERT_TRUE(code == 0 || code == StagedFiles::kTestCrashStatus) << "step " << k << ": status " << code;
      const PublishRecovery r = recoverPublishing(dir);
      EXPECT_TRUE(r.errors.empty()) << r.errors.front();
      std::vector<std::string> names;
      for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
      std::sort(names.begin(), names.end());
      const bool oldX = readFile(xdmf) == "old xdmf";
      if (oldX) {
        ++olds;
        const std::vector<std::string> expected =
            withH5 ? std::vector<std::string>{"e.h5", "e.xdmf"} : std::vector<std::string>{"e.xdmf"};
        EXPECT_EQ(names, expected) << "step " << k;
        if (withH5) {
          EXPECT_EQ(readFile(h5), "old h5") << "step " << k;
        }
      } else {
        ++news;
        EXPECT_EQ(names, (std::vector<std::string>{"e.h5", "e.xdmf"})) << "step " << k;
        EXPECT_GT(H5Fis_hdf5(h5.c_str()), 0) << "step " << k;
        EXPECT_NE(readFile(xdmf).find(">e.h5:/particles/position<"), std::string::npos) << "step " << k;
      }
      if (code == 0) {
        EXPECT_FALSE(oldX);
        break;
      }
    }
    EXPECT_GT(olds, 0);
    EXPECT_GT(news, 0);
  }
}

// ---- templates from the history ----------------------------------------------

TEST(SessionTemplateFromHistory, RecordsTheRegionOverTheFrameRange) {
  Fixture fx;
  TemplateDatabase out(fx.tmp.file("recorded"));  // created on demand
  const std::vector<double> lo = {0, 0.2}, hi = {0.25, 0.6};
  const TemplateEntry e = fx.session->recordTemplate(out, "fromhist", lo, hi, 2, 5, false);
  EXPECT_EQ(e.name, "fromhist");
  EXPECT_EQ(e.dimension, 2);
  EXPECT_EQ(e.frames, 4u);
  EXPECT_EQ(e.frameRate, 60);
  EXPECT_EQ(e.regionMin, lo);
  EXPECT_EQ(e.regionMax, hi);
  EXPECT_EQ(fx.tmp.entries(), (std::vector<std::string>{"recorded", "templates"}));

  const auto loaded = out.load<2>("fromhist");
  const Template<2>& t = loaded->templ();
  ASSERT_EQ(t.frameCount(), 4u);
  EXPECT_EQ(t.header.frameRate, 60);
  EXPECT_EQ(t.header.particleRadius, double(Real(0.02)));
  EXPECT_EQ(t.header.supportRadius, double(Real(0.08)));
  EXPECT_EQ(t.header.restDensity, 1000);
  EXPECT_EQ(t.header.createdBy, std::string("flowclip ") + FLOWCLIP_VERSION + " session s1");
  EXPECT_EQ(json::parse(t.header.recipe), fx.session->sceneJson());
  const double r = 0.02;
  for (size_t k = 0; k < 4; ++k) {
    const FramePtr snap = fx.session->frame(int(2 + k));
    ASSERT_TRUE(snap);
    // The particles of the snapshot inside the region, as recorded.
    std::vector<size_t> in;
    for (size_t i = 0; i < snap->particles(); ++i) {
      const double x = snap->position(i, 0), y = snap->position(i, 1);
      if (x >= lo[0] && x <= hi[0] && y >= lo[1] && y <= hi[1]) in.push_back(i);
    }
    const TemplateFrame<2>& fr = t.frames[k];
    ASSERT_EQ(fr.size(), in.size()) << "frame " << k;
    EXPECT_GT(fr.size(), 10u);
    EXPECT_LT(fr.size(), 100u);
    double vmax = 0;
    for (size_t i : in) vmax = std::max({vmax, std::abs(snap->velocity(i, 0)), std::abs(snap->velocity(i, 1))});
    EXPECT_GT(vmax, 0.01);
    for (size_t j = 0; j < fr.size(); ++j) {
      // Inside the region (the template's positions carry 0.01 r of error).
      for (int d = 0; d < 2; ++d) {
        EXPECT_GE(fr.x[j][d], lo[size_t(d)] - 0.01 * r);
        EXPECT_LE(fr.x[j][d], hi[size_t(d)] + 0.01 * r);
      }
      // The file orders particles by Morton code: match by position.
      size_t best = in[0];
      double bestD = std::numeric_limits<double>::max();
      for (size_t i : in) {
        const double dd = std::hypot(snap->position(i, 0) - fr.x[j][0], snap->position(i, 1) - fr.x[j][1]);
        if (dd < bestD) bestD = dd, best = i;
      }
      EXPECT_LT(bestD, 0.02 * r);
      // Template velocities: within half a step of max|v| / 1023.
      for (int d = 0; d < 2; ++d) EXPECT_NEAR(fr.v[j][d], snap->velocity(best, d), vmax / 1023 + 1e-5);
      // The lattice particle's mass: rest density × lattice volume ≈ (2r)².
      EXPECT_NEAR(fr.mass[j], 1000 * 4 * r * r, 1000 * 4 * r * r * 0.01);
      EXPECT_EQ(fr.phase[j], snap->phase[best]);
    }
  }
}

TEST(SessionTemplateFromHistory, ErrorsThrowAndLeaveNoFile) {
  Fixture fx(4);
  TemplateDatabase out(fx.tmp.file("recorded"));
  Session& s = *fx.session;
  const std::vector<double> lo = {0, 0}, hi = {0.5, 1};
  auto expectMessage = [](auto&& call, const std::string& text, auto tag) {
    using E = decltype(tag);
    try {
      call();
      ADD_FAILURE() << "expected an exception saying " << text;
    } catch (const E& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
  };
  // A frame of the range that is not in the history is named.
  expectMessage([&] { s.recordTemplate(out, "t", lo, hi, 2, 9, false); }, "frame 5 is not in the history",
                std::out_of_range(""));
  // Regions.
  expectMessage([&] { s.recordTemplate(out, "t", {0, 0, 0}, hi, 0, 1, false); }, "region_min must have 2 values",
                std::invalid_argument(""));
  expectMessage([&] { s.recordTemplate(out, "t", lo, {0.5, std::nan("")}, 0, 1, false); }, "region_max[1]",
                std::invalid_argument(""));
  expectMessage([&] { s.recordTemplate(out, "t", lo, {0.5, 0}, 0, 1, false); }, "region_max[1] must be greater",
                std::invalid_argument(""));
  expectMessage([&] { s.recordTemplate(out, "t", {0.8, 0.8}, {0.9, 0.9}, 0, 1, false); }, "no liquid particle",
                std::invalid_argument(""));
  // Range and name.
  EXPECT_THROW(s.recordTemplate(out, "t", lo, hi, 3, 1, false), std::invalid_argument);
  EXPECT_THROW(s.recordTemplate(out, "../t", lo, hi, 0, 1, false), DatabaseError);
  EXPECT_FALSE(fs::exists(out.directory()));

  // Exists: refused without force (the file untouched), replaced with it.
  s.recordTemplate(out, "t", lo, hi, 0, 1, false);
  const std::string before = readFile(out.pathFor("t"));
  expectMessage([&] { s.recordTemplate(out, "t", lo, hi, 0, 3, false); }, "already exists", DatabaseError(""));
  EXPECT_EQ(readFile(out.pathFor("t")), before);
  EXPECT_EQ(out.entry("t").frames, 2u);
  EXPECT_EQ(s.recordTemplate(out, "t", lo, hi, 0, 3, true).frames, 4u);
  EXPECT_EQ(out.load<2>("t")->templ().frameCount(), 4u);
  // Only the template itself: no staged or backup file stays.
  std::vector<std::string> names;
  for (const auto& p : fs::directory_iterator(out.directory())) names.push_back(p.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{"t.h5"});
}

}  // namespace
}  // namespace fc::service
