// SurfaceExport (export/surface_export.cpp): formats by name, a frame's
// files all or none, a manifest only for a complete export.
#include "export/surface_export.h"
#include "hdf5_test_util.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

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
