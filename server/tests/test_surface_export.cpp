// SurfaceExport (export/surface_export.cpp): formats by name, a frame's
// files all or none, a manifest only for a complete export.
#include "export/surface_export.h"
#include "hdf5_test_util.h"

#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <openvdb/io/File.h>

#include <array>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>

namespace fc {
namespace {

namespace fs = std::filesystem;
using test::TempDir;

// Writes a file, then fails on the frame given: the test's broken disk.
class FailingExporter : public Exporter {
 public:
  static inline int failAt = -1;
  void frame(const ParticleFrame& f, const Surface*, FrameFiles& files) override {
    std::ofstream(files.add(frameFileName(info_.name, f.index, "txt"))) << "partial";
    if (f.index == failAt) throw std::runtime_error("disk full");
  }
};

void registerFailing() {
  registerBuiltinExporters();
  ExporterRegistry::instance().add("test_failing", {"fails at FailingExporter::failAt", {},
                                                    [](const ParamValues&) { return std::make_unique<FailingExporter>(); }});
}

ParticleFrame droplet(int index) {
  ParticleFrame f;
  f.index = index;
  f.time = index / 60.0;
  for (int i = 0; i < 8; ++i) {
    f.position.insert(f.position.end(), {0.02f * (i & 1), 0.02f * ((i >> 1) & 1), 0.02f * (i >> 2)});
    f.velocity.insert(f.velocity.end(), {0, -1, 0});
    f.kind.push_back(0);
    f.phase.push_back(0);
  }
  return f;
}

ExportInfo info(const std::string& dir) {
  ExportInfo i;
  i.name = "drop";
  i.directory = dir;
  i.particleRadius = 0.01;
  i.frameRate = 60;
  i.createdBy = "test";
  return i;
}

// The loops of an SVG path's d attribute "M x y L x y ... Z ...", in metres (y flipped back).
std::vector<std::vector<std::array<double, 2>>> svgLoops(const std::string& file) {
  std::ifstream in(file);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t d = text.find(" d=\"");
  EXPECT_NE(d, std::string::npos);
  std::istringstream path(text.substr(d + 4, text.find('"', d + 4) - d - 4));
  std::vector<std::vector<std::array<double, 2>>> loops;
  std::string token;
  while (path >> token) {
    if (token == "Z") continue;
    if (token[0] == 'M') loops.emplace_back();
    const double x = std::stod(token.substr(1));
    double y = 0;
    path >> y;
    loops.back().push_back({x, -y});
  }
  return loops;
}

double signedArea(const std::vector<std::array<double, 2>>& loop) {
  double a = 0;
  for (size_t k = 0; k < loop.size(); ++k) {
    const auto& p = loop[k];
    const auto& q = loop[(k + 1) % loop.size()];
    a += 0.5 * (p[0] * q[1] - q[0] * p[1]);
  }
  return a;
}

TEST(SurfaceExport, SvgOutlinesA2DLiquidWithItsHolesAndDroplets) {
  TempDir dir;
  const double r = 0.01;
  ParticleFrame f;
  f.index = 3;
  const auto add = [&](double x, double y) {
    f.position.insert(f.position.end(), {float(x), float(y), 0.0f});
    f.velocity.insert(f.velocity.end(), {0, 0, 0});
    f.kind.push_back(0);
    f.phase.push_back(0);
  };
  // A 30 x 20 block with a 10 x 8 hole, and a droplet of four particles beside it.
  size_t liquid = 0;
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 20; ++j)
      if (!(i >= 10 && i < 20 && j >= 6 && j < 14)) add(2 * r * i, 2 * r * j), ++liquid;
  for (int k = 0; k < 4; ++k) add(0.8 + 2 * r * (k & 1), 0.2 + 2 * r * (k >> 1)), ++liquid;
  ExportInfo i = info(dir.file(""));
  i.dimension = 2;
  {
    SurfaceExport e(i, {"svg"}, surfaceSettingsTable().defaults());
    e.writeFrame(f);
    e.close();
  }
  const auto loops = svgLoops(dir.file("drop.0003.svg"));
  ASSERT_EQ(loops.size(), 3u);  // the block's outside, its hole, the droplet
  int outer = 0, holes = 0;
  double area = 0;
  for (const auto& l : loops) {
    const double a = signedArea(l);
    (a > 0 ? outer : holes) += 1;
    area += a;
  }
  EXPECT_EQ(outer, 2);
  EXPECT_EQ(holes, 1);
  // The outline lies about a radius beyond the outer particles: the liquid's area, within a few percent.
  const double particles = double(liquid) * 4 * r * r;
  std::printf("svg: %zu loops, area %.5f m2 (particles %.5f)\n", loops.size(), area, particles);
  EXPECT_NEAR(area / particles, 1.0, 0.08);
  // Two droplets half a kilometre apart diagonally: the outline costs their band, not the square between.
  ParticleFrame far;
  far.index = 4;
  for (const double at : {0.0, 500.0})
    for (int k = 0; k < 4; ++k) {
      far.position.insert(far.position.end(), {float(at + 2 * r * (k & 1)), float(at + 2 * r * (k >> 1)), 0.0f});
      far.velocity.insert(far.velocity.end(), {0, 0, 0});
      far.kind.push_back(0);
      far.phase.push_back(0);
    }
  {
    SurfaceExport e(i, {"svg"}, surfaceSettingsTable().defaults());
    e.writeFrame(far);
    e.close();
  }
  const auto apart = svgLoops(dir.file("drop.0004.svg"));
  ASSERT_EQ(apart.size(), 2u);
  EXPECT_GT(signedArea(apart[0]), 0);
  EXPECT_GT(signedArea(apart[1]), 0);
  // A 3D scene has no outline: refused before anything is written.
  ExportInfo three = info(dir.file("3d"));
  EXPECT_THROW(SurfaceExport(three, {"svg"}, surfaceSettingsTable().defaults()), ExportSetupError);
}

TEST(SurfaceExport, FormatsAreKnownNamesGivenOnce) {
  EXPECT_EQ(parseFormats("vdb, ply,usd"), (std::vector<std::string>{"vdb", "ply", "usd"}));
  EXPECT_THROW(parseFormats("vdb,stl"), ExportSetupError);
  EXPECT_THROW(parseFormats("ply,ply"), ExportSetupError);
  EXPECT_THROW(parseFormats(" , "), ExportSetupError);
}

TEST(SurfaceExport, AFailedFrameLeavesNoneOfItsFilesAndNoManifest) {
  registerFailing();
  TempDir dir;
  FailingExporter::failAt = 2;
  SurfaceExport e(info(dir.file("")), {"ply", "test_failing"}, surfaceSettingsTable().defaults());
  e.writeFrame(droplet(0));
  e.writeFrame(droplet(1));
  EXPECT_THROW(e.writeFrame(droplet(2)), std::runtime_error);
  // Frames 0 and 1 whole, nothing of frame 2 (its mesh was written before the failure), no manifest.
  EXPECT_EQ(dir.entries(), (std::vector<std::string>{"drop.0000.ply", "drop.0000.txt", "drop.0001.ply",
                                                          "drop.0001.txt"}));
}

TEST(SurfaceExport, ANewExportRemovesTheOldManifestUntilItCompletes) {
  registerFailing();
  TempDir dir;
  FailingExporter::failAt = -1;
  {
    SurfaceExport e(info(dir.file("")), {"points"}, surfaceSettingsTable().defaults());
    e.writeFrame(droplet(0));
    e.close();
  }
  EXPECT_TRUE(fs::exists(dir.file("drop.export.json")));
  SurfaceExport again(info(dir.file("")), {"points"}, surfaceSettingsTable().defaults());
  EXPECT_FALSE(fs::exists(dir.file("drop.export.json")));
  again.writeFrame(droplet(0));
  again.close();
  EXPECT_TRUE(fs::exists(dir.file("drop.export.json")));
}

// A frame without liquid still has its two grids, set up as a liquid
// frame's: a reader sees one kind of grid through the whole sequence.
TEST(SurfaceExport, AnEmptyFramesGridsAreALiquidFramesKind) {
  registerBuiltinExporters();
  TempDir dir;
  SurfaceExport e(info(dir.file("")), {"vdb"}, surfaceSettingsTable().defaults());
  e.writeFrame(droplet(0));
  ParticleFrame none;
  none.index = 1;
  none.time = 1 / 60.0;
  e.writeFrame(none);
  e.close();
  openvdb::initialize();
  std::vector<openvdb::GridPtrVecPtr> frames;
  for (const char* name : {"drop.0000.vdb", "drop.0001.vdb"}) {
    openvdb::io::File file(dir.file(name));
    file.open();
    frames.push_back(file.getGrids());
    file.close();
  }
  ASSERT_EQ(frames[0]->size(), 2u);
  ASSERT_EQ(frames[1]->size(), 2u);
  EXPECT_FALSE((*frames[0])[0]->empty());
  for (size_t g = 0; g < 2; ++g) {
    const auto& full = (*frames[0])[g];
    const auto& empty = (*frames[1])[g];
    EXPECT_TRUE(empty->empty());
    EXPECT_EQ(empty->getName(), full->getName());
    EXPECT_EQ(empty->valueType(), full->valueType());
    EXPECT_EQ(empty->getGridClass(), full->getGridClass());
    EXPECT_EQ(empty->getVectorType(), full->getVectorType()) << full->getName();
  }
}

TEST(SurfaceExport, RefusesANameThatIsNotAFileName) {
  TempDir dir;
  ExportInfo i = info(dir.file(""));
  for (const char* bad : {"", "../up", ".hidden", "a/b"}) {
    i.name = bad;
    EXPECT_THROW(SurfaceExport(i, {"ply"}, surfaceSettingsTable().defaults()), ExportSetupError) << bad;
  }
}

}  // namespace
}  // namespace fc
