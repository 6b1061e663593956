// What `flowclip bench accuracy` measures (bench/accuracy_metrics.h): the
// Martin & Moyce reference as committed, the surge front and compression of
// exported frames, the RMS against the reference, Pareto fronts and the
// preset rule.
#include "bench/accuracy_metrics.h"
#include "bench/exported_frames.h"
#include "io/frame_export.h"
#include "sph/phase.h"
#include "tests/hdf5_test_util.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <string>
#include <vector>

namespace fc {
namespace {

using fc::test::TempDir;

const std::string kMartinMoyce = std::string(FLOWCLIP_SOURCE_DIR) + "/bench/data/martin_moyce_1952.csv";

TEST(MartinMoyceData, IsTheTabulatedHalfInchSeries) {
  const SurgeCurve mm = readSurgeCurve(kMartinMoyce);
  ASSERT_EQ(mm.T.size(), 15u);
  EXPECT_DOUBLE_EQ(mm.T.front(), 0.41);
  EXPECT_DOUBLE_EQ(mm.Z.front(), 1.11);
  EXPECT_DOUBLE_EQ(mm.T.back(), 3.33);
  EXPECT_DOUBLE_EQ(mm.Z.back(), 4.11);
  // The front was timed at marks on the floor: with a = 2.25 in every
  // Z a is a quarter inch (2.5, 2.75, then every half inch from 3.25),
  // to the table's two decimals.
  for (size_t i = 0; i < mm.Z.size(); ++i) {
    const double inches = mm.Z[i] * 2.25;
    EXPECT_NEAR(inches, std::round(inches * 4) / 4, 0.012) << "point " << i;
    if (i > 0) EXPECT_GT(mm.Z[i], mm.Z[i - 1]) << "the front only advances";
  }
}

// The residual column height at the wall (their Table 6), read as a curve
// of its own: 17 points falling from 0.94 to 0.06 of the initial height at
// quarter-inch marks on a 4.5 in column.
TEST(MartinMoyceData, IsTheTabulatedResidualHeightSeries) {
  const SurgeCurve h = readSurgeCurve(std::string(FLOWCLIP_SOURCE_DIR) + "/bench/data/martin_moyce_1952_height.csv", "tau,H");
  ASSERT_EQ(h.T.size(), 17u);
  EXPECT_DOUBLE_EQ(h.T.front(), 0.56);
  EXPECT_DOUBLE_EQ(h.Z.front(), 0.94);
  EXPECT_DOUBLE_EQ(h.T.back(), 7.4);
  EXPECT_DOUBLE_EQ(h.Z.back(), 0.06);
  for (size_t i = 0; i < h.Z.size(); ++i) {
    const double inches = h.Z[i] * 4.5;
    EXPECT_NEAR(inches, std::round(inches * 4) / 4, 0.025) << "point " << i;
    if (i > 0) EXPECT_LT(h.Z[i], h.Z[i - 1]) << "the column only falls";
  }
  // The surge curve's reader refuses it under the surge's header.
  EXPECT_THROW(readSurgeCurve(std::string(FLOWCLIP_SOURCE_DIR) + "/bench/data/martin_moyce_1952_height.csv"),
               std::runtime_error);
}

TEST(MartinMoyceData, BadFilesNameTheLine) {
  TempDir dir;
  const auto write = [&](const std::string& text) {
    std::ofstream(dir.file("c.csv")) << text;
    return dir.file("c.csv");
  };
  const auto message = [](const std::string& path) {
    try {
      readSurgeCurve(path);
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message(write("# c\nT,Z\n1,2\n1,3\n")).find("line 4: T must increase"), std::string::npos);
  EXPECT_NE(message(write("x,y\n1,2\n")).find("line 1: expected the header 'T,Z'"), std::string::npos);
  EXPECT_NE(message(write("T,Z\n1;2\n")).find("line 2: expected two numbers"), std::string::npos);
  EXPECT_NE(message(write("T,Z\n")).find("no points"), std::string::npos);
  EXPECT_NE(message(dir.file("missing.csv")).find("cannot be read"), std::string::npos);
}

TEST(SurgeRms, IsTheRootMeanSquareOfTheInterpolatedDifference) {
  const SurgeCurve reference{{1, 2, 3}, {1, 2, 3}};
  // Runs sampled at other times than the reference's, linear in T so that
  // the interpolation is exact: 0.1 ahead, then ahead by 0.1 (T - 2).
  SurgeCurve ahead, tilted;
  for (double T = 0; T <= 4; T += 0.3) {
    ahead.T.push_back(T), ahead.Z.push_back(T + 0.1);
    tilted.T.push_back(T), tilted.Z.push_back(T + 0.1 * (T - 2));
  }
  EXPECT_NEAR(surgeRms(ahead, reference), 0.1, 1e-12);
  EXPECT_NEAR(surgeRms(tilted, reference), std::sqrt(0.02 / 3), 1e-12);
  const SurgeCurve mm = readSurgeCurve(kMartinMoyce);
  EXPECT_NEAR(surgeRms(mm, mm), 0.0, 1e-12);
  // A run that ends before the last reference point is not compared.
  const SurgeCurve shortRun{{0, 1, 2}, {1, 1.5, 2.5}};
  EXPECT_THROW(surgeRms(shortRun, mm), std::invalid_argument);
}

TEST(Interpolate, IsLinearBetweenSamples) {
  const std::vector<double> x{0, 1, 3}, y{0, 2, 0};
  const auto v = interpolateAt(x, y, {0, 0.5, 1, 2, 3});
  EXPECT_DOUBLE_EQ(v[0], 0);
  EXPECT_DOUBLE_EQ(v[1], 1);
  EXPECT_DOUBLE_EQ(v[2], 2);
  EXPECT_DOUBLE_EQ(v[3], 1);
  EXPECT_DOUBLE_EQ(v[4], 0);
  EXPECT_THROW(interpolateAt(x, y, {3.5}), std::invalid_argument);
}

// An export of one frame: a 0.5 m x 1 m column on a 2r lattice (r = 0.01),
// its lower half compressed by 1 %, its top row below rest density (kernel
// deficiency), plus one droplet far ahead; and one temporary particle.
ExportedFrames columnExport(TempDir& dir) {
  ExportHeader h;
  h.sceneName = "column";
  h.dimension = 2;
  h.particleRadius = 0.01;
  h.frameRate = 60;
  h.phases = {Phase{}};
  h.domainMin = {0, 0};
  h.domainMax = {3, 1.5};
  h.createdBy = "flowclip tests";
  FluidParticles<2> f;
  for (int i = 0; i < 25; ++i)
    for (int j = 0; j < 50; ++j) {
      f.add(Vec<2>(0.01f + 0.02f * i, 0.01f + 0.02f * j), Vec<2>::Zero(), 0.4f, 0);
      f.density.back() = j < 25 ? 1010 : j == 49 ? 600 : 1000;
    }
  f.add(Vec<2>(2.0f, 0.01f), Vec<2>::Zero(), 0.4f, 0);  // spray
  f.density.back() = 400;
  f.add(Vec<2>(0.25f, 1.2f), Vec<2>::Zero(), 0.4f, 0, ParticleKind::Temporary);
  f.density.back() = 1000;
  FrameExporter<2> ex(dir.file("column.h5"), h);
  ex.writeFrame(0, 0.0, f);
  ex.writeFrame(1, 1.0 / 60, f);
  ex.close();
  return readExportedFrames(dir.file("column.h5"));
}

TEST(LiquidFrame, FrontIgnoresSprayAndCompressionIgnoresTheSurface) {
  TempDir dir;
  const ExportedFrames e = columnExport(dir);
  ASSERT_EQ(e.frames(), 2u);
  EXPECT_DOUBLE_EQ(e.time[1], 1.0 / 60);
  const LiquidFrame m = measureLiquidFrame(e, 1, 0.0);
  EXPECT_EQ(m.particles, 1252u);
  // 0.1 % of 1252 particles: the spray particle (and at most one more) lie
  // ahead of the front; the column's last centres are at 0.49, its edge at 0.5.
  EXPECT_NEAR(m.front, 0.5, 1e-6);
  // 625 particles at 1 %, the rest (surface and spray included) not compressed.
  EXPECT_NEAR(m.avgCompressionPct, 625.0 / 1252 * 1.0, 1e-4);
  EXPECT_NEAR(m.maxCompressionPct, 1.0, 1e-4);
  EXPECT_NEAR(m.volumeRatio, (625 / 1.01 + 627) / 1252, 1e-6);
  EXPECT_THROW(measureLiquidFrame(e, 2, 0.0), std::out_of_range);
}

TEST(ExportedFrames, RefusesWhatIsNotAFramesFile) {
  TempDir dir;
  std::ofstream(dir.file("x.h5")) << "not hdf5";
  try {
    readExportedFrames(dir.file("x.h5"));
    FAIL() << "no error";
  } catch (const ExportReadError& e) {
    EXPECT_NE(std::string(e.what()).find(dir.file("x.h5")), std::string::npos) << e.what();
  }
  EXPECT_THROW(readExportedFrames(dir.file("missing.h5")), ExportReadError);
}

// A column of 10 × 20 particles on the lattice in a 2D box 20 r wide, at
// times 0, 0.5, 1 and 2 s, its pressure ρ0 g (H - y) below the highest
// centre plus r. A particle moves at 3 m/s in the frame at 0.5 s and at
// 0.02 m/s in the frame at 1 s. In the last frame the column is `sink`
// radii lower (its pressure kept) and the pressure of the row 9 r deep (the
// interior's top band) is `shallowScale` times its own.
ExportedFrames restingColumnExport(double sink, double shallowScale) {
  const double r = 0.01, g = 9.81;
  ExportedFrames e;
  e.dimension = 2;
  e.particleRadius = r;
  e.phaseRestDensity = {1000};
  e.time = {0, 0.5, 1, 2};
  e.offset = {0};
  for (size_t f = 0; f < e.time.size(); ++f) {
    const bool last = f + 1 == e.time.size();
    const double H = 40 * r;
    for (int i = 0; i < 10; ++i)
      for (int j = 0; j < 20; ++j) {
        const double x = r + 2 * r * i, y = r + 2 * r * j;
        e.position.push_back(float(x));
        e.position.push_back(float(last ? y - sink * r : y));
        e.pressure.push_back(float(1000 * g * (H - y) * (last && j == 15 ? shallowScale : 1.0)));
        const bool mover = i == 5 && j == 10;
        e.velocity.push_back(mover && f == 1 ? 3.0f : mover && f == 2 ? 0.02f : 0.0f);
        e.velocity.push_back(0.0f);
        e.density.push_back(1000);
        e.phase.push_back(0);
        e.kind.push_back(uint8_t(ParticleKind::Liquid));
      }
    e.offset.push_back(e.offset.back() + 200);
  }
  return e;
}

const double kColumnMin[2] = {0, 0}, kColumnMax[2] = {0.2, 0.6};

TEST(RestingColumn, ALatticeAtRestReadsItsRestDistanceAndItsHydrostaticPressure) {
  const RestingColumnMeasure m =
      measureRestingColumn(restingColumnExport(0, 1), kColumnMin, kColumnMax, 9.81, 1.5, 1.0);
  EXPECT_NEAR(m.floorRowGap, 1.0, 1e-5);
  EXPECT_NEAR(m.sideRowGap, 1.0, 1e-5);
  EXPECT_NEAR(m.closestApproach, 1.0, 1e-5);
  EXPECT_NEAR(m.surfaceChange, 0.0, 1e-4);
  EXPECT_NEAR(m.maxSpeedAfter, 0.02, 1e-7) << "the 3 m/s before 1 s is not counted";
  EXPECT_NEAR(m.floorRowPressure, 1.0, 1e-5);
  // The surface from the volume, 200 cells of (2r)² over 20 r: 40 r. The interior, up to 8 r below it and over
  // 6 r from the side walls, in twelve bands of 32 r / 12 from the floor up.
  EXPECT_EQ(m.bands, 12u);
  EXPECT_NEAR(m.bandPressureErrorPct, 0.0, 1e-3);
  EXPECT_NEAR(m.bandPressureStdPct, 0.0, 1e-3);
}

TEST(RestingColumn, ASunkColumnReadsItsDistanceAndAWrongBandItsError) {
  // Settled over the last frame alone: the rows 0.6 r from the floor and the top 0.4 r down. The pressure is
  // read against the surface the volume defines, which stays: the floor row, 39 r below it before, is now 39.4 r.
  const RestingColumnMeasure sunk =
      measureRestingColumn(restingColumnExport(0.4, 1), kColumnMin, kColumnMax, 9.81, 1.5, 1.0);
  EXPECT_NEAR(sunk.floorRowGap, 0.6, 1e-4);
  EXPECT_NEAR(sunk.sideRowGap, 1.0, 1e-5);
  EXPECT_NEAR(sunk.closestApproach, 0.6, 1e-4);
  EXPECT_NEAR(sunk.surfaceChange, -0.4, 1e-4);
  EXPECT_NEAR(sunk.floorRowPressure, 39.0 / 39.4, 1e-5);
  // The top band 10 % high in the last frame: 10 % over it; over the last two frames a mean 5 % high whose
  // frame-to-frame standard deviation (1 and 1.1) is 5 √2 %.
  const ExportedFrames wrong = restingColumnExport(0, 1.1);
  const RestingColumnMeasure last = measureRestingColumn(wrong, kColumnMin, kColumnMax, 9.81, 1.5, 1.0);
  EXPECT_NEAR(last.bandPressureErrorPct, 10.0, 1e-3);
  EXPECT_NEAR(last.bandPressureStdPct, 0.0, 1e-3);
  const RestingColumnMeasure two = measureRestingColumn(wrong, kColumnMin, kColumnMax, 9.81, 1.0, 1.0);
  EXPECT_NEAR(two.bandPressureErrorPct, 5.0, 1e-3);
  EXPECT_NEAR(two.bandPressureStdPct, 5.0 * std::sqrt(2.0), 1e-3);
  EXPECT_NEAR(two.floorRowPressure, 1.0, 1e-5);
}

TEST(RestingColumn, RefusesAnExportWithoutPressureOrThatEndsBeforeItSettles) {
  ExportedFrames e = restingColumnExport(0, 1);
  EXPECT_THROW(measureRestingColumn(e, kColumnMin, kColumnMax, 9.81, 2.5, 1.0), std::invalid_argument);
  e.pressure.clear();
  EXPECT_THROW(measureRestingColumn(e, kColumnMin, kColumnMax, 9.81, 1.5, 1.0), std::invalid_argument);
}

TEST(Pareto, KeepsExactlyTheUndominatedPoints) {
  //                      0    1    2    3    4    5
  const std::vector<double> cost{1.0, 2.0, 2.0, 4.0, 8.0, 3.0};
  const std::vector<double> err{0.9, 0.5, 0.6, 0.2, 0.1, 0.5};
  const auto on = paretoFront(cost, err);
  EXPECT_EQ(on, (std::vector<bool>{true, true, false, true, true, false}));
  // Point 3 left out of the competition: 5 (3.0, 0.5) is still dominated by 1.
  const auto without3 = paretoFront(cost, err, {true, true, true, false, true, true});
  EXPECT_EQ(without3, (std::vector<bool>{true, true, false, false, true, false}));
  // Identical points do not dominate each other.
  EXPECT_EQ(paretoFront({1, 1}, {2, 2}), (std::vector<bool>{true, true}));
}

TEST(Presets, DraftCheapestFinalMostAccuratePreviewTheKnee) {
  // A front falling steeply, then flat: the knee is at (2, 0.1).
  const std::vector<double> cost{1, 2, 4, 8, 16, 3};
  const std::vector<double> err{1.0, 0.1, 0.08, 0.07, 0.06, 1.0};
  const auto on = paretoFront(cost, err);
  ASSERT_FALSE(on[5]);
  const PresetPick p = pickPresets(cost, err, on);
  EXPECT_EQ(p.draft, 0);
  EXPECT_EQ(p.final, 4);
  EXPECT_EQ(p.preview, 1);
  // Two front points: preview is final.
  const PresetPick two = pickPresets({1, 2}, {1, 0.5}, {true, true});
  EXPECT_EQ(two.draft, 0);
  EXPECT_EQ(two.preview, 1);
  EXPECT_EQ(two.final, 1);
  EXPECT_EQ(pickPresets({1}, {1}, {false}).draft, -1);
}

}  // namespace
}  // namespace fc
