#pragma once
// What `flowclip bench accuracy` measures on a run
// (docs/benchmarks/accuracy.md): the liquid's surge front, compression and volume per exported
// frame, the surge front against Martin & Moyce (1952) [MM52], and the Pareto front
// and presets of a set of (cost, error) points.
#include "bench/exported_frames.h"
#include <string>
#include <vector>

namespace fc {

// A surge-front curve in Martin & Moyce's units: T = t sqrt(2g/a), Z = x/a.
struct SurgeCurve {
  std::vector<double> T, Z;
};

// A "T,Z" CSV (bench/data/martin_moyce_1952.csv): '#' comment lines, a
// header line, then one point per line in increasing T. Throws
// std::runtime_error naming the file and line of what is wrong. `columns`:
// the header, for another curve in the same form (the residual column
// height, "tau,H").
SurgeCurve readSurgeCurve(const std::string& path, const std::string& columns = "T,Z");

struct LiquidFrame {
  double time = 0;
  size_t particles = 0;       // liquid particles (kinds Liquid and Temporary)
  // Leading edge of the liquid along +x from `wallX`, m: the 99.9th
  // percentile of the particles' x plus one radius (a particle stands for
  // the cell around its centre). The same front as the DamBreak tests
  // (server/tests/test_dambreak.cpp): an SPH surge tip sheds single
  // particles ahead of it, Martin & Moyce timed the water's edge, not spray.
  double front = 0;
  // Σ m/max(ρ, ρ0) over Σ m/ρ0, particles of equal rest volume: the
  // liquid's volume relative to its rest volume. Surface particles miss
  // neighbours and read ρ < ρ0 without being expanded (kernel deficiency),
  // so only compression counts.
  double volumeRatio = 1;
  // Compression max(ρ/ρ0 - 1, 0), in percent: average and largest.
  double avgCompressionPct = 0;
  double maxCompressionPct = 0;
};

// Frame `frame` of an export. The densities are those of the frame's last
// substep (computed before its advection), as the exporter stores them.
LiquidFrame measureLiquidFrame(const ExportedFrames& frames, size_t frame, double wallX);

// How a column of liquid resting in a box sits against its walls, from an
// export of it (docs/benchmarks/accuracy.md, the `rest` group), as the
// tests of the boundary models and of the readable pressure measure it.
// Gravity along -y; distances in particle radii r. Rows: the liquid within
// 2 r of the floor, and within 2 r of a side wall between 4 r above the
// floor and 4 r below the top. Top: the highest centre plus r. Pressure
// against ρ0 g (H - y), H the surface the liquid's volume defines (each
// particle a lattice cell (2r)^D, over the floor's area). Settled: the
// frames from `settledFrom` s on.
struct RestingColumnMeasure {
  double floorRowGap = 0;       // the floor row's mean distance from the floor, settled (rest: 1)
  double sideRowGap = 0;        // the side rows' mean distance from their walls, settled (rest: 1)
  double closestApproach = 0;   // the nearest any centre came to a wall, every frame after the first
  double surfaceChange = 0;     // settled top minus the first frame's (+: risen)
  double maxSpeedAfter = 0;     // fastest particle in the frames from `speedFrom` s on, m/s
  double floorRowPressure = 0;  // Σ p / Σ ρ0 g (H - y) of the floor row, settled mean (rest: 1)
  // The interior (over 6 r from the side walls, up to 8 r below H) in up to twelve bands from the floor
  // up, each band's mean p / ρ0 g (H - y) per settled frame. The worst band's |mean over the frames - 1| and
  // the largest frame-to-frame standard deviation, in percent.
  double bandPressureErrorPct = 0;
  double bandPressureStdPct = 0;
  size_t bands = 0;
};

// Throws std::invalid_argument where the export lacks velocity or pressure,
// has no frame at or after `settledFrom`/`speedFrom`, or the column is too
// shallow for an interior.
RestingColumnMeasure measureRestingColumn(const ExportedFrames& frames, const double* domainMin,
                                          const double* domainMax, double gravity, double settledFrom,
                                          double speedFrom);

// y(x) interpolated linearly at each of `at`; x increasing. Points outside
// [x.front(), x.back()] are an error (std::invalid_argument saying how far
// the data reaches): a run too short for the reference is not compared.
std::vector<double> interpolateAt(const std::vector<double>& x, const std::vector<double>& y,
                                  const std::vector<double>& at);

// sqrt(mean((simulated(T_i) - Z_i)^2)) over the reference points.
double surgeRms(const SurgeCurve& simulated, const SurgeCurve& reference);
// mean(simulated(T_i) - Z_i) over the reference points: how far ahead (+) the simulated curve runs.
double surgeBias(const SurgeCurve& simulated, const SurgeCurve& reference);

// on[i]: no other point is at most as costly and at most as wrong, and
// strictly better in one (both minimised). Only points with eligible[i]
// compete (an empty `eligible` means all).
std::vector<bool> paretoFront(const std::vector<double>& cost, const std::vector<double>& error,
                              const std::vector<bool>& eligible = {});

// Presets from a Pareto front (indices into cost/error, -1 if none):
// draft = the cheapest front point, final = the most accurate, preview =
// the knee between them: the front point furthest below the straight line
// from draft to final in log10(cost)-log10(error) (equal factors of cost
// and error weigh the same). With fewer than three front points, preview
// is final.
struct PresetPick {
  long draft = -1, preview = -1, final = -1;
};
PresetPick pickPresets(const std::vector<double>& cost, const std::vector<double>& error,
                       const std::vector<bool>& onFront);

}  // namespace fc
