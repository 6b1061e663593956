// The pressure a user reads (exports' /particles/pressure, FluidParticles::
// meanPressure): on the shipped resting columns, every frame of the last
// second, the interior particles' pressure against ρ0 g depth. The frame
// mean must be the hydrostatic pressure and hold still from frame to frame,
// where the solver's own pressure of the frame's last substep jumps around
// it; both are printed.
//
// FLOWCLIP_TEST_VERBOSE=1 prints one line per frame.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>
#include "physics_checks.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

namespace fc {
namespace {

struct Series {
  std::vector<double> mean, last;  // per frame: interior p / ρ0 g depth, averaged over the particles
};

double average(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0 : s / double(v.size());
}
double spread(const std::vector<double>& v) {
  const double m = average(v);
  double s = 0;
  for (double x : v) s += (x - m) * (x - m);
  return v.size() > 1 ? std::sqrt(s / double(v.size() - 1)) : 0;
}

template <int D>
Series restingColumn(const std::string& sceneFile, const std::string& boundary, double seconds, double from) {
  auto json = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/" + sceneFile);
  if (!boundary.empty()) json["boundary"] = {{"method", boundary}};
  const SimulationSetup<D> setup = parseScene<D>(json);
  Simulation<D> sim(setup);
  const double r = sim.particleRadius(), rho0 = setup.phases.at(0).restDensity, g = setup.gravity.norm();
  const auto& dom = setup.domain;
  const auto& f = sim.fluid;
  FrameChecks checks;
  Series out;
  while (sim.time() < seconds - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    if (sim.time() < from - 1e-9) continue;
    double top = -1e30;
    for (size_t i = 0; i < f.size(); ++i) top = std::max(top, double(f.x[i][1]));
    const double H = top + r;
    double mean = 0, last = 0;
    size_t n = 0;
    for (size_t i = 0; i < f.size(); ++i) {
      // Three diameters from every wall and from the surface.
      bool interior = f.x[i][1] < H - 6 * r;
      for (int d = 0; d < D; ++d) interior = interior && f.x[i][d] > dom.min[d] + 6 * r && f.x[i][d] < dom.max[d] - 6 * r;
      if (!interior) continue;
      const double hydro = rho0 * g * (H - f.x[i][1]);
      mean += f.meanPressure[i] / hydro;
      last += f.pressure[i] / hydro;
      ++n;
    }
    EXPECT_GT(n, 50u) << "interior particles";
    out.mean.push_back(mean / double(std::max<size_t>(n, 1)));
    out.last.push_back(last / double(std::max<size_t>(n, 1)));
    if (verbose())
      std::printf("%s t=%.3f readable %.4f, last substep %.4f (%zu particles)\n", sceneFile.c_str(), sim.time(),
                  out.mean.back(), out.last.back(), n);
  }
  checks.finish(int(sim.frame()));
  std::printf("[ measured ] %s, boundary %s, %.1f-%.1f s: interior pressure / rho0 g depth, readable %.4f (frame-to-frame "
              "sd %.4f, range %.4f-%.4f), the last substep's %.4f (sd %.4f, range %.4f-%.4f)\n",
              sceneFile.c_str(), boundary.empty() ? "the scene's" : boundary.c_str(), from, seconds,
              average(out.mean), spread(out.mean), *std::min_element(out.mean.begin(), out.mean.end()),
              *std::max_element(out.mean.begin(), out.mean.end()), average(out.last), spread(out.last),
              *std::min_element(out.last.begin(), out.last.end()), *std::max_element(out.last.begin(), out.last.end()));
  return out;
}

template <int D>
void expectReadable(const Series& s, double meanTolerance, double sdBound) {
  ASSERT_FALSE(s.mean.empty());
  EXPECT_NEAR(average(s.mean), 1.0, meanTolerance) << "interior pressure / rho0 g depth, averaged over the frames";
  EXPECT_LT(spread(s.mean), sdBound) << "frame-to-frame standard deviation";
  EXPECT_LT(spread(s.mean), spread(s.last)) << "no steadier than the solver's own";
}

TEST(ReadablePressure, RestingColumnIsHydrostaticAndSteady2D) {
  // Measured 0.998, sd 0.004 (the last substep's: sd 0.033).
  expectReadable<2>(restingColumn<2>("hydrostatic2d.json", "", 2.0, 1.0), 0.02, 0.01);
}

TEST(ReadablePressure, RestingColumnIsHydrostaticAndSteady3D) {
  // Measured 0.94, sd 0.022 (the last substep's: 0.82, sd 0.31). The depth
  // counts from the highest particle, which rides above the 3D surface.
  expectReadable<3>(restingColumn<3>("hydrostatic3d.json", "", 2.0, 1.0), 0.08, 0.05);
}

}  // namespace
}  // namespace fc
