// Small fixtures shared by the instance, session and service tests: a
// synthetic template written to a database directory and a small 2D tank.
#pragma once

#include "control/template.h"
#include "io/template_file.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

namespace fc::test {

// 4 × 4 particles on a lattice (spacing 0.02 m) one spacing inside the
// capture region [lo, hi], rising 1 mm per frame at 0.06 m/s, `frames`
// frames at 60 fps (duration (frames − 1) / 60 s), written to DIR/NAME.h5.
template <int D>
void writeSmallTemplate(const std::string& dir, const std::string& name, int frames, const std::vector<double>& lo,
                        const std::vector<double>& hi) {
  Template<D> t;
  TemplateHeader& h = t.header;
  h.name = name;
  h.dimension = D;
  h.frameRate = 60;
  h.particleRadius = 0.01;
  h.supportRadius = 0.04;
  h.restDensity = 1000;
  h.regionMin = lo;
  h.regionMax = hi;
  h.recipe = "{}";
  h.createdBy = "flowclip tests";
  const double dx = 2 * h.particleRadius;
  for (int f = 0; f < frames; ++f) {
    TemplateFrame<D> fr;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        Vec<D> x;
        for (int d = 0; d < D; ++d) x[d] = Real(lo[size_t(d)] + dx);
        x[0] += Real(i * dx);
        x[1] += Real(j * dx + 0.001 * f);
        fr.x.push_back(x);
        fr.v.push_back(Vec<D>::UnitY() * Real(0.06));
        fr.mass.push_back(Real(1000 * std::pow(dx, D)));
        fr.phase.push_back(0);
      }
    t.frames.push_back(std::move(fr));
  }
  std::filesystem::create_directories(dir);
  writeTemplate<D>((std::filesystem::path(dir) / (name + ".h5")).string(), t);
}

// Polls `done` until it holds or `timeout` passes (keep timeouts generous:
// tests must pass on a loaded machine).
template <class F>
bool waitFor(F done, std::chrono::milliseconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  while (!done()) {
    if (std::chrono::steady_clock::now() > until) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

// 100 particles (a 10 × 10 block at r = 0.02 m) in the corner of a 1 m 2D
// tank: a scene that simulates a frame in milliseconds.
inline nlohmann::json smallTankScene(const std::string& name = "box") {
  nlohmann::json j = nlohmann::json::parse(R"({
    "dimension": 2, "particle_radius": 0.02,
    "domain": {"min": [0, 0], "max": [1, 1]},
    "fluid_blocks": [{"min": [0, 0], "max": [0.4, 0.4]}]
  })");
  j["name"] = name;
  return j;
}

}  // namespace fc::test
