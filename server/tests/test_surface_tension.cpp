// Surface tension of Akinci, Akinci & Teschner 2013 [AAT13] (effect
// surface_tension_akinci2013, sph/surface_tension/akinci2013.cpp):
//  1. its kernels: the 2D normalisations give the same continuum surface
//     tension (cohesion) and work of adhesion as the paper's 3D ones;
//  2. every pair term is antisymmetric (momentum conserved) and phases do not
//     pull on each other;
//  3. a 2D square of liquid in zero gravity relaxes towards a disk, and
//     without the effect it stays a square;
//  4. the capillary time-step bound keeps a strong tension stable;
//  5. parameters out of range are scene errors naming the key.
// Scenes are built in code as JSON and go through parseScene, like files.
//
// FLOWCLIP_TEST_VERBOSE=1 prints one line per frame.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <random>
#include <string>
#include <type_traits>
#include <vector>

namespace fc {
namespace {

using nlohmann::json;
using V2 = Eigen::Vector2d;

bool verbose() {
  const char* v = std::getenv("FLOWCLIP_TEST_VERBOSE");
  return v && *v && std::string(v) != "0";
}

double secondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// ---------------------------------------------------------------------------
// 1. Kernels

// ∫_0^h f(r) r^p dr by the midpoint rule (the kernels are smooth pieces; the
// adhesion kernel's 1/4 power is integrable at both ends).
template <class F>
double radialMoment(F&& f, double h, int p, int n = 200000) {
  double s = 0;
  const double dr = h / n;
  for (int k = 0; k < n; ++k) {
    const double r = (k + 0.5) * dr;
    s += double(f(Real(r))) * std::pow(r, p);
  }
  return s * dr;
}

// Splitting a continuum with pair force -u'(r) x^ costs, per interface area,
// (c_D / (D+1)) n^2 ∫ u' r^(D+1) dr with c_3 = π, c_2 = 2: the surface
// tension of the cohesion term is (π/8) γ ρ² ∫ C r⁴ dr in 3D and
// (1/3) γ ρ² ∫ C r³ dr in 2D. Both must equal (21/7040) γ ρ² h².
TEST(SurfaceTensionKernels, CohesionGivesTheSameSurfaceTensionIn2DAnd3D) {
  const double h = 0.04;
  const CohesionKernel<2> c2{Real(h)};
  const CohesionKernel<3> c3{Real(h)};
  const double s3 = std::numbers::pi / 8 * radialMoment([&](Real r) { return c3.W(r); }, h, 4);
  const double s2 = 1.0 / 3 * radialMoment([&](Real r) { return c2.W(r); }, h, 3);
  const double expected = CohesionKernel<2>::sigmaPerGammaRho2H2() * h * h;
  std::printf("[ measured ] sigma / (gamma rho^2): 3D %.6e, 2D %.6e, (21/7040) h^2 = %.6e\n", s3, s2, expected);
  EXPECT_NEAR(s3 / expected, 1.0, 1e-4);
  EXPECT_NEAR(s2 / expected, 1.0, 1e-4);
  // The paper's shape: continuous at h/2, zero at h, repulsive below 0.2729 h,
  // peak k h^6/64 at h/2 (3D: 1/(2π h³)).
  for (const auto* c : {&c3}) {
    EXPECT_NEAR(c->W(Real(0.5 * h) * Real(0.99999)) / c->W(Real(0.5 * h) * Real(1.00001)), 1.0, 1e-3);
    EXPECT_EQ(c->W(Real(h * 1.0001)), 0);
    EXPECT_LT(c->W(Real(0.27 * h)), 0);
    EXPECT_GT(c->W(Real(0.275 * h)), 0);
    EXPECT_NEAR(double(c->W(Real(0.5 * h))), 1 / (2 * std::numbers::pi * h * h * h), 1e-3 / (h * h * h));
  }
  EXPECT_LT(c2.W(Real(0.27 * h)), 0);
  EXPECT_GT(c2.W(Real(0.275 * h)), 0);
}

// Work of adhesion per area between liquid and solid half-spaces: the same
// moments of A; the 2D kernel must match the paper's 3D one.
TEST(SurfaceTensionKernels, AdhesionGivesTheSameWorkOfAdhesionIn2DAnd3D) {
  const double h = 0.04;
  const AdhesionKernel<2> a2{Real(h)};
  const AdhesionKernel<3> a3{Real(h)};
  const double w3 = std::numbers::pi / 8 * radialMoment([&](Real r) { return a3.W(r); }, h, 4);
  const double w2 = 1.0 / 3 * radialMoment([&](Real r) { return a2.W(r); }, h, 3);
  std::printf("[ measured ] work of adhesion / (beta rho^2): 3D %.6e, 2D %.6e\n", w3, w2);
  EXPECT_NEAR(w2 / w3, 1.0, 1e-3);
  EXPECT_EQ(a3.W(Real(0.5 * h)), 0);
  EXPECT_EQ(a3.W(Real(0.3 * h)), 0);
  EXPECT_GT(a3.W(Real(0.75 * h)), 0);
  EXPECT_EQ(a3.W(Real(1.01 * h)), 0);
}

// ---------------------------------------------------------------------------
// Scenes

// A 2D square block of `n` x `n` particles (r = 0.005 m) in the middle of a
// tank it never reaches, zero gravity. `effects` null: no "effects" key.
json squareScene(int n, double nu, const json& effects, const json& settings = json(), double shift = 0) {
  const double r = 0.005, side = n * 2 * r, tank = side * 2 + 0.2;
  const double lo = (tank - side) / 2 + shift;
  json s = {
      {"dimension", 2},
      {"particle_radius", r},
      {"domain", {{"min", {0, 0}}, {"max", {tank, tank}}}},
      {"gravity", {0, 0}},
      {"phases", json::array({{{"name", "water"}, {"rest_density", 1000}, {"viscosity", nu}}})},
      {"fluid_blocks", json::array({{{"min", {lo, lo}}, {"max", {lo + side, lo + side}}}})},
  };
  if (!effects.is_null()) s["effects"] = effects;
  if (!settings.is_null()) s["settings"] = settings;
  return s;
}

json kXsphAdhesion() { return {{"name", "viscosity_xsph"}, {"coefficient", 0.3}}; }

json surfaceTension(double gamma) {
  return {{"name", "surface_tension_akinci2013"}, {"surface_tension", gamma}};
}

std::vector<V2> positions(const Simulation<2>& sim) {
  std::vector<V2> p;
  p.reserve(sim.fluid.size());
  for (const auto& x : sim.fluid.x) p.push_back(x.cast<double>());
  return p;
}

V2 centroid(const std::vector<V2>& p) {
  V2 c = V2::Zero();
  for (const V2& x : p) c += x;
  return c / double(p.size());
}

double cross(const V2& o, const V2& a, const V2& b) { return (a - o).x() * (b - o).y() - (a - o).y() * (b - o).x(); }

// Convex hull (Andrew's monotone chain), counter-clockwise.
std::vector<V2> convexHull(std::vector<V2> p) {
  std::sort(p.begin(), p.end(), [](const V2& a, const V2& b) { return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y()); });
  std::vector<V2> h(2 * p.size());
  size_t k = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  for (size_t i = p.size() - 1, t = k + 1; i > 0; --i) {
    while (k >= t && cross(h[k - 2], h[k - 1], p[i - 1]) <= 0) --k;
    h[k++] = p[i - 1];
  }
  h.resize(k - 1);
  return h;
}

struct Shape {
  double hullCircularity = 0;  // 4π area / perimeter² of the convex hull: square π/4 = 0.785, disk 1
  double sectorRatio = 0;      // outer radius about the centroid, min / max over 36 sectors: square 0.71, disk 1
  double maxRadius = 0;        // farthest particle from the centroid, m
};

Shape measureShape(const std::vector<V2>& p) {
  Shape s;
  const std::vector<V2> hull = convexHull(p);
  double area = 0, perimeter = 0;
  for (size_t i = 0; i < hull.size(); ++i) {
    const V2& a = hull[i];
    const V2& b = hull[(i + 1) % hull.size()];
    area += 0.5 * (a.x() * b.y() - b.x() * a.y());
    perimeter += (b - a).norm();
  }
  s.hullCircularity = 4 * std::numbers::pi * area / (perimeter * perimeter);
  const V2 c = centroid(p);
  constexpr int kSectors = 36;
  std::vector<double> outer(kSectors, 0);
  for (const V2& x : p) {
    const V2 d = x - c;
    const double angle = std::atan2(d.y(), d.x()) + std::numbers::pi;
    const int k = std::min(kSectors - 1, int(angle / (2 * std::numbers::pi) * kSectors));
    outer[size_t(k)] = std::max(outer[size_t(k)], d.norm());
    s.maxRadius = std::max(s.maxRadius, d.norm());
  }
  s.sectorRatio = *std::min_element(outer.begin(), outer.end()) / *std::max_element(outer.begin(), outer.end());
  return s;
}

// The radius of the largest empty disk centred inside the convex hull, m:
// the largest distance from a point of the hull (sampled every r/2) to its
// nearest particle. About 0.7 spacings in a settled liquid; larger where the
// shape has holes or deep concavities.
double largestGap(const std::vector<V2>& p, double step) {
  const std::vector<V2> hull = convexHull(p);
  V2 lo = p[0], hi = p[0];
  for (const V2& x : p) lo = lo.cwiseMin(x), hi = hi.cwiseMax(x);
  double gap = 0;
  for (double y = lo.y(); y <= hi.y(); y += step)
    for (double x = lo.x(); x <= hi.x(); x += step) {
      const V2 q(x, y);
      bool inside = true;
      for (size_t i = 0; i < hull.size() && inside; ++i) inside = cross(hull[i], hull[(i + 1) % hull.size()], q) >= 0;
      if (!inside) continue;
      double d2 = 1e30;
      for (const V2& a : p) d2 = std::min(d2, (a - q).squaredNorm());
      gap = std::max(gap, std::sqrt(d2));
    }
  return gap;
}

V2 momentum(const Simulation<2>& sim) {
  V2 p = V2::Zero();
  for (size_t i = 0; i < sim.fluid.size(); ++i) p += double(sim.fluid.mass[i]) * sim.fluid.v[i].cast<double>();
  return p;
}

V2 centreOfMass(const Simulation<2>& sim) {
  V2 c = V2::Zero();
  double m = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    c += double(sim.fluid.mass[i]) * sim.fluid.x[i].cast<double>();
    m += sim.fluid.mass[i];
  }
  return c / m;
}

struct SquareRun {
  Shape start, end;
  double comShift = 0;           // m
  double momentumDrift = 0;      // max over frames of |Σ m v| / Σ m |v|
  double keMax = 0, keEnd = 0, keLateMax = 0;  // keLateMax: largest KE over the last quarter
  double maxRadiusOverRun = 0;   // farthest any particle got from the centroid
  double equivalentRadius = 0;   // sqrt(N (2r)² / π): the disk of the block's area
  double gapStart = 0, gapEnd = 0;  // largestGap at the start and the end, m
  size_t particles = 0, escaped = 0;
  int substeps = 0;
  double minDt = 1e30, maxDt = 0;
  double stepMs = 0, effectMs = 0;  // wall time per substep: whole step, non-pressure stage
  bool finite = true;
  double wallSeconds = 0;
};

SquareRun runSquare(const json& scene, double seconds) {
  Simulation<2> sim(parseScene<2>(scene));
  SquareRun run;
  run.particles = sim.fluid.size();
  run.equivalentRadius = std::sqrt(double(run.particles) * 4 * sim.particleRadius() * sim.particleRadius() / std::numbers::pi);
  run.start = measureShape(positions(sim));
  run.gapStart = largestGap(positions(sim), 0.5 * sim.particleRadius());
  const V2 com0 = centreOfMass(sim);
  const auto t0 = std::chrono::steady_clock::now();
  double stepMs = 0, effectMs = 0;
  while (sim.time() < seconds - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    run.substeps += fs.substeps;
    run.escaped += fs.escapedParticles;
    run.minDt = std::min(run.minDt, fs.minDt);
    run.maxDt = std::max(run.maxDt, fs.maxDt);
    stepMs += fs.wallMs;
    effectMs += fs.nonPressureMs;
    if (!fs.finite) {
      run.finite = false;
      break;
    }
    double scale = 0;
    for (size_t i = 0; i < sim.fluid.size(); ++i) scale += double(sim.fluid.mass[i]) * double(sim.fluid.v[i].norm());
    if (scale > 0) run.momentumDrift = std::max(run.momentumDrift, momentum(sim).norm() / scale);
    const Shape s = measureShape(positions(sim));
    run.maxRadiusOverRun = std::max(run.maxRadiusOverRun, s.maxRadius);
    run.keMax = std::max(run.keMax, fs.kineticEnergy);
    if (fs.time >= 0.75 * seconds - 1e-9) run.keLateMax = std::max(run.keLateMax, fs.kineticEnergy);
    run.keEnd = fs.kineticEnergy;
    if (verbose())
      std::printf("  t=%.3f hull %.4f sectors %.4f rmax %.4f KE %.3e vmax %.3e substeps %d dt [%.2e, %.2e] iter %d+%d\n",
                  fs.time, s.hullCircularity, s.sectorRatio, s.maxRadius, fs.kineticEnergy, fs.maxSpeed, fs.substeps,
                  fs.minDt, fs.maxDt, fs.divergenceIterations, fs.densityIterations);
  }
  run.wallSeconds = secondsSince(t0);
  run.end = measureShape(positions(sim));
  run.gapEnd = largestGap(positions(sim), 0.5 * sim.particleRadius());
  if (const char* dump = std::getenv("FLOWCLIP_ST_DUMP")) {
    if (FILE* out = std::fopen(dump, "w")) {
      for (const auto& x : sim.fluid.x) std::fprintf(out, "%g %g\n", double(x[0]), double(x[1]));
      std::fclose(out);
    }
  }
  run.comShift = (centreOfMass(sim) - com0).norm();
  run.stepMs = run.substeps ? stepMs / run.substeps : 0;
  run.effectMs = run.substeps ? effectMs / run.substeps : 0;
  return run;
}

void printRun(const char* what, const SquareRun& r) {
  std::printf("[ measured ] %s: %zu particles, %d substeps (dt %.2e - %.2e s): hull circularity %.4f -> %.4f, "
              "sector ratio %.4f -> %.4f, largest gap %.2f r -> %.2f r; centre-of-mass shift %.2e m, momentum drift %.2e; KE max %.3e, last "
              "quarter max %.3e, end %.3e; farthest particle %.4f m (equivalent disk radius %.4f m); %zu escaped; "
              "%.3f ms/substep, of which non-pressure %.3f ms; %.2f s wall\n",
              what, r.particles, r.substeps, r.minDt, r.maxDt, r.start.hullCircularity, r.end.hullCircularity,
              r.start.sectorRatio, r.end.sectorRatio, r.gapStart / 0.005, r.gapEnd / 0.005, r.comShift, r.momentumDrift, r.keMax, r.keLateMax, r.keEnd,
              r.maxRadiusOverRun, r.equivalentRadius, r.escaped, r.stepMs, r.effectMs, r.wallSeconds);
}


// ---------------------------------------------------------------------------
// 2. Pair terms: momentum and phases

// One application of the effect on a jittered block in free space (no wall
// within reach, so no adhesion and no boundary term): Σ_i m_i a_i = 0 up to
// rounding, because every pair term is antisymmetric.
TEST(SurfaceTension, PairTermsConserveMomentum) {
  json scene = squareScene(20, 0, json::array({surfaceTension(1)}));
  Simulation<2> sim(parseScene<2>(scene));
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> jitter(-0.3f, 0.3f);
  for (auto& x : sim.fluid.x) x += Real(sim.particleRadius()) * Vec<2>(jitter(rng), jitter(rng));
  sim.refreshNeighbors();
  size_t nearWall = 0;
  for (uint16_t c : sim.boundaryNeighbors) nearWall += c > 0;
  ASSERT_EQ(nearWall, 0u);
  const auto* entry = EffectRegistry<2>::instance().find("surface_tension_akinci2013");
  ASSERT_NE(entry, nullptr);
  ParamValues pv(entry->params);
  pv.set("surface_tension", 1);
  pv.set("adhesion", 1);  // no boundary in reach: must change nothing
  auto effect = entry->make(pv);
  effect->resize(sim.fluid.size());
  effect->init(sim);
  for (auto& a : sim.fluid.a) a.setZero();
  effect->addAccelerations(sim);
  V2 total = V2::Zero();
  double scale = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    total += double(sim.fluid.mass[i]) * sim.fluid.a[i].cast<double>();
    scale += double(sim.fluid.mass[i]) * double(sim.fluid.a[i].norm());
  }
  std::printf("[ measured ] jittered block, %zu particles: |Σ m a| / Σ m |a| = %.2e (Σ m |a| = %.3e N/m)\n",
              sim.fluid.size(), total.norm() / scale, scale);
  ASSERT_GT(scale, 0);
  EXPECT_LT(total.norm() / scale, 1e-5);
}

// Two touching blocks: of the same phase they attract each other; of two
// phases (same density) neither pulls the other, so the net force on each
// block (its internal pair forces cancel) is zero.
TEST(SurfaceTension, NoCohesionBetweenPhases) {
  auto netForceOnLeft = [](bool twoPhases) {
    json s = squareScene(10, 0, json::array({surfaceTension(1)}));
    s["phases"] = json::array({{{"name", "a"}, {"rest_density", 1000}}, {{"name", "b"}, {"rest_density", 1000}}});
    const double lo = s["fluid_blocks"][0]["min"][0], r = s["particle_radius"];
    s["fluid_blocks"] = json::array({
        {{"min", {lo, lo}}, {"max", {lo + 20 * r, lo + 20 * r}}, {"phase", "a"}},
        {{"min", {lo + 20 * r, lo}}, {"max", {lo + 40 * r, lo + 20 * r}}, {"phase", twoPhases ? "b" : "a"}},
    });
    Simulation<2> sim(parseScene<2>(s));
    sim.refreshNeighbors();
    const auto* entry = EffectRegistry<2>::instance().find("surface_tension_akinci2013");
    ParamValues pv(entry->params);
    pv.set("surface_tension", 1);
    auto effect = entry->make(pv);
    effect->resize(sim.fluid.size());
    effect->init(sim);
    for (auto& a : sim.fluid.a) a.setZero();
    effect->addAccelerations(sim);
    V2 left = V2::Zero();
    double scale = 0;
    const double mid = lo + 20 * r;
    for (size_t i = 0; i < sim.fluid.size(); ++i) {
      const V2 f = double(sim.fluid.mass[i]) * sim.fluid.a[i].cast<double>();
      scale += f.norm();
      if (sim.fluid.x[i][0] < mid) left += f;
    }
    return std::pair<V2, double>(left, scale);
  };
  const auto [same, sameScale] = netForceOnLeft(false);
  const auto [two, twoScale] = netForceOnLeft(true);
  std::printf("[ measured ] net force on the left block: same phase (%.3e, %.3e) N/m, two phases (%.3e, %.3e) N/m; "
              "Σ |F| %.3e / %.3e\n",
              same.x(), same.y(), two.x(), two.y(), sameScale, twoScale);
  EXPECT_GT(same.x(), 0.05 * sameScale / 200) << "the same phase must pull the left block towards the right one";
  EXPECT_LT(two.norm(), 1e-5 * twoScale) << "two phases must not pull on each other";
}

// Adhesion (eqs. 6-7) pulls liquid towards a wall: a 10 x 10 block in zero
// gravity, its left column one spacing from the left wall (within reach of
// the wall's boundary particles), gamma = 0, 0.2 s. With beta = 1 the net
// force of the first step points at the wall and the block's centre of mass
// moves towards it; with beta = 0 (default) neither happens.
TEST(SurfaceTension, AdhesionPullsTowardsTheWall) {
  auto run = [](double beta) {
    const double r = 0.005;
    json s = squareScene(10, 0, json::array({kXsphAdhesion(), {{"name", "surface_tension_akinci2013"}, {"surface_tension", 0}, {"adhesion", beta}}}));
    s["fluid_blocks"][0]["min"] = {2 * r, 0.2};
    s["fluid_blocks"][0]["max"] = {2 * r + 0.1, 0.3};
    Simulation<2> sim(parseScene<2>(s));
    const V2 com0 = centreOfMass(sim);
    double firstForceX = 0;
    bool finite = true;
    while (sim.time() < 0.2 - 1e-9) {
      const FrameStats fs = sim.advanceFrame();
      finite = finite && fs.finite;
      if (fs.frame == 1)
        for (size_t i = 0; i < sim.fluid.size(); ++i) firstForceX += double(sim.fluid.mass[i]) * double(sim.fluid.a[i][0]);
    }
    return std::tuple<double, double, bool>(centreOfMass(sim).x() - com0.x(), firstForceX, finite);
  };
  const auto [dxOn, fOn, finiteOn] = run(1);
  const auto [dxOff, fOff, finiteOff] = run(0);
  std::printf("[ measured ] block by the left wall, 0.2 s: centre of mass moved %.3e m with adhesion 1, %.3e m without; "
              "x force of the non-pressure stage at the end of frame 1: %.3e / %.3e N/m\n",
              dxOn, dxOff, fOn, fOff);
  EXPECT_TRUE(finiteOn && finiteOff);
  EXPECT_LT(fOn, 0) << "adhesion must pull towards the wall (-x)";
  EXPECT_EQ(fOff, 0) << "no adhesion, no gravity, gamma 0: no non-pressure force";
  EXPECT_LT(dxOn, dxOff - 0.1 * 0.005) << "with adhesion the block must move towards the wall";
}

// ---------------------------------------------------------------------------
// 3. A square relaxes towards a disk

// 30 x 30 particles (r = 0.005 m, a 0.3 m square, 900 particles), zero
// gravity, gamma = 2, XSPH c = 0.3 as the viscosity (it conserves momentum;
// viscosity_standard's m_j/rho_j weights do not at a free surface, which
// would blur the centre-of-mass check), 1.5 s at the default time-step
// settings (the capillary bound sets dt: 2.9 ms). Shapes, on the particle
// centres:
//   hull circularity, 4 pi A / P^2 of the convex hull: the square 0.785, a
//     disk cut from the same lattice 0.982;
//   sector ratio, min / max over 36 sectors of the outer radius about the
//     centroid: the square 0.718, the lattice disk 0.962;
//   largest gap, the largest empty disk centred inside the hull: 1.41 r in
//     the square, 4-5 r where a corner has pinched off into a loop of
//     particles around a void (seen with XSPH c = 0.1).
// Measured when written, with the square moved by 0, 0.05, 0.1, 0.137 m
// (the motion is chaotic, so the outcome varies with the start): hull
// 0.785 -> 0.971-0.978, sector ratio 0.718 -> 0.82-0.87, largest gap
// 1.43-1.74 r; centre of mass moved by <= 3e-8 m; the KE of the last quarter
// at most 5 % of its peak. The drop stalls short of a disk once damped
// (docs/physics/surface-tension.md), hence the sector-ratio bound 0.78.
constexpr int kSquareN = 30;
constexpr double kSquareGamma = 2, kSquareSeconds = 1.5;
const json kXsph = {{"name", "viscosity_xsph"}, {"coefficient", 0.3}};

TEST(SurfaceTension, SquareRelaxesToDisk) {
  const SquareRun run = runSquare(squareScene(kSquareN, 0, json::array({kXsph, surfaceTension(kSquareGamma)})), kSquareSeconds);
  printRun("square, surface tension gamma = 2", run);
  const double r = 0.005;
  ASSERT_TRUE(run.finite);
  EXPECT_EQ(run.escaped, 0u);
  EXPECT_NEAR(run.start.hullCircularity, std::numbers::pi / 4, 0.01) << "the start is a square";
  EXPECT_GT(run.end.hullCircularity, 0.96) << "hull circularity at the end (square 0.785, lattice disk 0.982)";
  EXPECT_GT(run.end.sectorRatio, 0.78) << "outer radius min/max over sectors (square 0.718, lattice disk 0.962)";
  EXPECT_LT(run.gapEnd, 2.5 * r) << "a hole or a deep notch in the drop";
  // Nothing leaves the drop: no particle ever farther than the square's
  // corners, and at the end all within the disk of the block's area + 4 r.
  EXPECT_LE(run.maxRadiusOverRun, run.start.maxRadius * 1.01);
  EXPECT_LT(run.end.maxRadius, run.equivalentRadius + 4 * r);
  // Pair forces only (no wall in reach): momentum stays zero, the centre of
  // mass stays put (1e-3 r allows float rounding).
  EXPECT_LT(run.momentumDrift, 1e-4) << "|Σ m v| / Σ m |v|, worst frame";
  EXPECT_LT(run.comShift, 1e-3 * r) << "centre of mass moved";
  // The damped drop settles: its kinetic energy decays.
  EXPECT_GT(run.keMax, 0);
  EXPECT_LT(run.keLateMax, 0.25 * run.keMax) << "largest KE over the last quarter vs the peak";
  EXPECT_LT(run.keEnd, 0.1 * run.keMax) << "KE at the end vs the peak";
}

// The same square without the effect (same damping): it stays a square, so
// the rounding above comes from the effect.
TEST(SurfaceTension, SquareStaysSquareWithoutEffect) {
  const SquareRun run = runSquare(squareScene(kSquareN, 0, json::array({kXsph})), kSquareSeconds);
  printRun("square, no surface tension", run);
  ASSERT_TRUE(run.finite);
  EXPECT_EQ(run.escaped, 0u);
  EXPECT_NEAR(run.end.hullCircularity, run.start.hullCircularity, 0.01);
  EXPECT_NEAR(run.end.sectorRatio, run.start.sectorRatio, 0.02);
  EXPECT_LT(run.gapEnd, 2.5 * 0.005);
}

// ---------------------------------------------------------------------------
// 4. The capillary time-step bound

// gamma = 20 at the default time-step settings: the bound caps dt (below the
// CFL and dt_max), and the run stays finite and bounded and still rounds.
TEST(SurfaceTension, StrongTensionStableAtTheBound) {
  const double gamma = 20, r = 0.005, rho0 = 1000, h = 4 * r;
  const double sigma = CohesionKernel<2>::sigmaPerGammaRho2H2() * gamma * rho0 * rho0 * h * h;
  const double dtCap = std::sqrt(rho0 * r * r * r / (2 * std::numbers::pi * sigma));
  const SquareRun run = runSquare(squareScene(kSquareN, 0, json::array({kXsph, surfaceTension(gamma)})), 0.5);
  printRun("square, gamma = 20, default time-step settings", run);
  std::printf("[ measured ] capillary step sqrt(rho0 r^3 / (2 pi sigma)) = %.3e s; largest substep %.3e s\n", dtCap,
              run.maxDt);
  ASSERT_TRUE(run.finite);
  EXPECT_EQ(run.escaped, 0u);
  EXPECT_LE(run.maxDt, dtCap * 1.0001) << "the bound must cap the step";
  EXPECT_LE(run.maxRadiusOverRun, run.start.maxRadius * 1.01);
  EXPECT_GT(run.end.hullCircularity, 0.95);
}

// `sigma` (N/m) in place of gamma: the run is the one with gamma = sigma /
// ((21/7040) rho0^2 h^2) at the scene's radius, at two radii (a liquid's
// surface tension stays its own when the resolution changes). The two runs
// differ only by the rounding of gamma (computed from the float support
// radius), which the solver's iteration counts amplify; a tenth more gamma
// differs by far more (measured: 0.0007 r and 0.013 r against 0.033 r and
// 0.16 r after 0.1 s).
TEST(SurfaceTension, SigmaInNewtonsPerMetreIsGammaAtTheScenesRadius) {
  const double sigma = 0.0728, rho0 = 1000;
  for (double r : {0.005, 0.0025}) {
    const double h = 4 * r, gamma = sigma / (CohesionKernel<2>::sigmaPerGammaRho2H2() * rho0 * rho0 * h * h);
    const auto run = [&](const json& effects) {
      json scene = squareScene(12, 0, effects);
      scene["particle_radius"] = r;
      Simulation<2> sim(parseScene<2>(scene));
      while (sim.time() < 0.1 - 1e-9) sim.advanceFrame();
      return positions(sim);
    };
    const std::vector<V2> byGamma = run(json::array({kXsph, surfaceTension(gamma)}));
    const std::vector<V2> bySigma = run(json::array({kXsph, {{"name", "surface_tension_akinci2013"}, {"sigma", sigma}}}));
    const std::vector<V2> stronger = run(json::array({kXsph, surfaceTension(1.1 * gamma)}));
    const std::vector<V2> without = run(json::array({kXsph}));
    ASSERT_EQ(byGamma.size(), bySigma.size());
    const auto farthest = [&](const std::vector<V2>& a) {
      double d = 0;
      for (size_t i = 0; i < a.size(); ++i) d = std::max(d, (a[i] - byGamma[i]).norm());
      return d / r;
    };
    const double differ = farthest(bySigma), tenthMore = farthest(stronger), moved = farthest(without);
    std::printf("[ measured ] r = %g m: gamma %.4g for sigma %.4g N/m; the sigma run %.2e r from the gamma run, "
                "1.1 gamma %.3f r, no tension %.3f r\n", r, gamma, sigma, differ, tenthMore, moved);
    EXPECT_GT(moved, 0.3) << "the tension must act in 0.1 s";
    EXPECT_LT(differ, 0.2 * tenthMore) << "sigma must give the run of its gamma";
  }
}

// ---------------------------------------------------------------------------
// 5. Scene validation and pipeline

TEST(SurfaceTensionScene, ParametersOutOfRangeNameTheKey) {
  auto expectError = [](const json& effect, const std::string& path, const std::string& mention) {
    const json s = squareScene(4, 0, json::array({"viscosity_standard", effect}));
    try {
      parseScene<2>(s);
      ADD_FAILURE() << "expected SceneError at " << path;
    } catch (const SceneError& e) {
      EXPECT_EQ(e.path, path) << e.what();
      EXPECT_NE(std::string(e.what()).find(mention), std::string::npos) << e.what();
    }
  };
  expectError({{"name", "surface_tension_akinci2013"}, {"surface_tension", -0.1}}, "effects[1].surface_tension", "[0, 100]");
  expectError({{"name", "surface_tension_akinci2013"}, {"surface_tension", 1e3}}, "effects[1].surface_tension", "[0, 100]");
  expectError({{"name", "surface_tension_akinci2013"}, {"adhesion", -1}}, "effects[1].adhesion", "[0, 100]");
  expectError({{"name", "surface_tension_akinci2013"}, {"surface_tension", "strong"}}, "effects[1].surface_tension", "number");
  expectError({{"name", "surface_tension_akinci2013"}, {"gamma", 1}}, "effects[1].gamma", "surface_tension");
  expectError({{"name", "surface_tension_akinci2013"}, {"sigma", -0.07}}, "effects[1].sigma", "[0, 10]");
}

TEST(SurfaceTensionScene, DefaultsAndPipeline) {
  const SimulationSetup<2> setup = parseScene<2>(squareScene(4, 0, json::array({"surface_tension_akinci2013"})));
  ASSERT_EQ(setup.effects.size(), 1u);
  EXPECT_DOUBLE_EQ(setup.effects[0].values.get("surface_tension"), 0.05);  // SPlisHSPlasH's default
  EXPECT_DOUBLE_EQ(setup.effects[0].values.get("adhesion"), 0);            // off
  Simulation<2> sim(setup);
  EXPECT_EQ(sim.pipelineStages(), (std::vector<std::string>{"pressure:dfsph", "effect:surface_tension_akinci2013"}));
  const json s3 = {
      {"dimension", 3},
      {"particle_radius", 0.05},
      {"domain", {{"min", {0, 0, 0}}, {"max", {1, 1, 1}}}},
      {"fluid_blocks", json::array({{{"min", {0, 0, 0}}, {"max", {0.5, 0.5, 0.5}}}})},
      {"effects", json::array({{{"name", "surface_tension_akinci2013"}, {"adhesion", 0.01}}})},
  };
  Simulation<3> sim3(parseScene<3>(s3));
  EXPECT_EQ(sim3.pipelineStages(), (std::vector<std::string>{"pressure:dfsph", "effect:surface_tension_akinci2013"}));
  const FrameStats fs = sim3.advanceFrame();
  EXPECT_TRUE(fs.finite);
  EXPECT_EQ(fs.escapedParticles, 0u);
}

// Exploration (not a check): FLOWCLIP_ST_GAMMA, FLOWCLIP_ST_NU, FLOWCLIP_ST_N, FLOWCLIP_ST_T,
// FLOWCLIP_ST_XSPH, FLOWCLIP_ST_DT (fixed step), FLOWCLIP_ST_SCENE (a scene file instead),
// FLOWCLIP_ST_DUMP (final positions to a text file), FLOWCLIP_ST_SHIFT (moves the square, m).
TEST(SurfaceTension, DISABLED_Explore) {
  auto env = [](const char* k, double d) {
    const char* v = std::getenv(k);
    return v ? std::atof(v) : d;
  };
  const double gamma = env("FLOWCLIP_ST_GAMMA", 1), nu = env("FLOWCLIP_ST_NU", 0.005);
  const int n = int(env("FLOWCLIP_ST_N", 30));
  const double T = env("FLOWCLIP_ST_T", 1);
  const double xsph = env("FLOWCLIP_ST_XSPH", 0);
  json effects = xsph > 0 ? json::array({{{"name", "viscosity_xsph"}, {"coefficient", xsph}}}) : json::array();
  if (nu > 0) effects.push_back("viscosity_standard");
  if (gamma > 0) effects.push_back(surfaceTension(gamma));
  json settings = json::object();
  if (const char* dt = std::getenv("FLOWCLIP_ST_DT")) settings = {{"dt_min", std::atof(dt)}, {"dt_max", std::atof(dt)}};
  const char* file = std::getenv("FLOWCLIP_ST_SCENE");
  const SquareRun r =
      runSquare(file ? loadSceneJson(file) : squareScene(n, nu, effects, settings, env("FLOWCLIP_ST_SHIFT", 0)), T);
  printRun("explore", r);
  // Reference: the same number of lattice points cut as a disk.
  {
    std::vector<V2> disk;
    const double s = 0.01;
    for (int i = -n; i <= n; ++i)
      for (int j = -n; j <= n; ++j)
        if (std::hypot(i, j) * s <= r.equivalentRadius) disk.push_back(V2(i * s, j * s));
    const Shape d = measureShape(disk);
    std::printf("[ measured ] lattice disk of radius %.4f m (%zu points): hull %.4f, sectors %.4f\n", r.equivalentRadius,
                disk.size(), d.hullCircularity, d.sectorRatio);
  }
}


// The explicit term's stability limit, measured (not a check; run with
// --gtest_also_run_disabled_tests): a 2D square (30 x 30) and a 3D cube
// (10^3) with XSPH damping at a fixed step dt = f dt_cap, where
// dt_cap = sqrt(rho0 r^3 / (2 pi sigma)) and sigma = (21/7040) gamma rho0^2 h^2,
// for several gamma and radii; frames last 4 dt so that every substep is dt.
// A run is unstable when it goes non-finite, a particle ends up farther than
// 1.5x the equivalent disk (sphere) radius from the centroid, or its peak
// kinetic energy exceeds 4x that of the run at f = 0.5.
template <int D>
struct BlobRun {
  bool finite = true;
  double keMax = 0, farthest = 0, equivalent = 0, maxDt = 0;
  int substeps = 0;
};

template <int D>
BlobRun<D> runBlob(int n, double radius, double gamma, double dt, double seconds) {
  const double side = n * 2 * radius, tank = side * 2 + 0.2, lo = (tank - side) / 2;
  json s = {
      {"dimension", D},
      {"particle_radius", radius},
      {"domain", {{"min", std::vector<double>(D, 0.0)}, {"max", std::vector<double>(D, tank)}}},
      {"gravity", std::vector<double>(D, 0.0)},
      {"fluid_blocks", json::array({{{"min", std::vector<double>(D, lo)}, {"max", std::vector<double>(D, lo + side)}}})},
      {"effects", json::array({{{"name", "viscosity_xsph"}, {"coefficient", 0.1}}, surfaceTension(gamma)})},
      {"settings", {{"dt_min", dt}, {"dt_max", dt}, {"frame_rate", 1 / (4 * dt)}}},
  };
  Simulation<D> sim(parseScene<D>(s));
  BlobRun<D> run;
  const double volume = double(sim.fluid.size()) * std::pow(2 * radius, D);
  run.equivalent = D == 2 ? std::sqrt(volume / std::numbers::pi) : std::cbrt(3 * volume / (4 * std::numbers::pi));
  while (sim.time() < seconds - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    run.substeps += fs.substeps;
    run.maxDt = std::max(run.maxDt, fs.maxDt);
    run.keMax = std::max(run.keMax, fs.kineticEnergy);
    if (!fs.finite) {
      run.finite = false;
      break;
    }
  }
  Vec<D> c = Vec<D>::Zero();
  for (const auto& x : sim.fluid.x) c += x;
  c /= Real(sim.fluid.size());
  for (const auto& x : sim.fluid.x) run.farthest = std::max(run.farthest, double((x - c).norm()));
  return run;
}

template <int D>
void sweepStability(int n, double radius, double gamma) {
  const std::vector<double> factors = {0.5, 1, 1.5, 2, 2.5, 3, 4, 5, 6, 8};
  const double rho0 = 1000, h = 4 * radius;
  const double sigma = CohesionKernel<D>::sigmaPerGammaRho2H2() * gamma * rho0 * rho0 * h * h;
  const double dtCap = std::sqrt(rho0 * radius * radius * radius / (2 * std::numbers::pi * sigma));
  double keRef = 0, firstUnstable = 0, lastStable = 0;
  for (const double f : factors) {
    const double dt = f * dtCap;
    if (dt > 0.1 || 1 / (4 * dt) < 1) break;
    const BlobRun<D> r = runBlob<D>(n, radius, gamma, dt, std::max(0.25, 100 * dtCap));
    if (keRef == 0) keRef = r.keMax;
    const bool unstable = !r.finite || r.farthest > 1.5 * r.equivalent || r.keMax > 4 * keRef;
    std::printf("[ measured ] %dD r=%g gamma=%g dt_cap=%.3e s: dt = %.2f dt_cap (largest substep %.2f dt_cap) -> %s "
                "(KE max %.3e, farthest %.4f m, equivalent radius %.4f m, %d substeps)\n",
                D, radius, gamma, dtCap, f, r.maxDt / dtCap, unstable ? "UNSTABLE" : "stable", r.keMax, r.farthest,
                r.equivalent, r.substeps);
    if (unstable) {
      firstUnstable = f;
      break;
    }
    lastStable = f;
  }
  std::printf("[ measured ] %dD r=%g gamma=%g: stable up to %.2f dt_cap, unstable at %.2f dt_cap\n", D, radius, gamma,
              lastStable, firstUnstable);
}

TEST(SurfaceTension, DISABLED_MeasureStabilityLimit) {
  for (const double radius : {0.005, 0.0025})
    for (const double gamma : {1.0, 4.0, 16.0}) sweepStability<2>(30, radius, gamma);
  for (const double gamma : {1.0, 16.0}) sweepStability<3>(10, 0.005, gamma);
}


// Cost of one application (not a check): FLOWCLIP_ST_SCENE (default the 2D
// benchmark dam break, 22 201 particles), the effect vs viscosity_standard on
// the same neighbourhoods, best of 30.
TEST(SurfaceTension, DISABLED_Cost) {
  const char* file = std::getenv("FLOWCLIP_ST_SCENE");
  const json scene = loadSceneJson(file ? file : std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/bench/dambreak2d_r005.json");
  auto time = []<int D>(Simulation<D>& sim, const char* name) {
    const auto* entry = EffectRegistry<D>::instance().find(name);
    auto effect = entry->make(ParamValues(entry->params));
    effect->resize(sim.fluid.size());
    effect->init(sim);
    double best = 1e30;
    for (int k = 0; k < 30; ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      effect->addAccelerations(sim);
      best = std::min(best, secondsSince(t0) * 1e3);
    }
    return best;
  };
  auto run = [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    Simulation<D> sim(parseScene<D>(scene));
    sim.refreshNeighbors();
    const double st = time(sim, "surface_tension_akinci2013"), visc = time(sim, "viscosity_standard");
    std::printf("[ measured ] %s: %zu particles, %.1f neighbours each: surface_tension_akinci2013 %.3f ms, "
                "viscosity_standard %.3f ms per application (best of 30, %d threads)\n",
                scene.value("name", "scene").c_str(), sim.fluid.size(),
                double(sim.search.dynamicNeighbors().pairs()) / double(sim.fluid.size()), st, visc, omp_get_max_threads());
  };
  if (sceneDimension(scene) == 2) run(std::integral_constant<int, 2>());
  else run(std::integral_constant<int, 3>());
}

}  // namespace
}  // namespace fc
