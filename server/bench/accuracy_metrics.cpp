#include "bench/accuracy_metrics.h"

#include "sph/phase.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace fc {

SurgeCurve readSurgeCurve(const std::string& path, const std::string& columns) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("surge curve '" + path + "': cannot be read");
  SurgeCurve c;
  std::string line;
  bool header = false;
  for (int n = 1; std::getline(in, line); ++n) {
    const auto where = [&] { return "surge curve '" + path + "' line " + std::to_string(n) + ": "; };
    if (line.empty() || line[0] == '#') continue;
    if (!header) {
      if (line.rfind(columns, 0) != 0) throw std::runtime_error(where() + "expected the header '" + columns + "'");
      header = true;
      continue;
    }
    std::istringstream s(line);
    double T = 0, Z = 0;
    char comma = 0;
    if (!(s >> T >> comma >> Z) || comma != ',' || !std::isfinite(T) || !std::isfinite(Z))
      throw std::runtime_error(where() + "expected two numbers '" + columns + "', got '" + line + "'");
    if (!c.T.empty() && !(T > c.T.back())) throw std::runtime_error(where() + columns.substr(0, columns.find(',')) + " must increase");
    c.T.push_back(T);
    c.Z.push_back(Z);
  }
  if (c.T.empty()) throw std::runtime_error("surge curve '" + path + "': no points");
  return c;
}

LiquidFrame measureLiquidFrame(const ExportedFrames& e, size_t frame, double wallX) {
  if (frame >= e.frames()) throw std::out_of_range("frame " + std::to_string(frame) + " is not in the export");
  LiquidFrame m;
  m.time = e.time[frame];
  const int D = e.dimension;
  std::vector<float> xs;
  double rest = 0, volume = 0, compression = 0;
  for (uint64_t k = e.offset[frame]; k < e.offset[frame + 1]; ++k) {
    if (e.kind[k] == uint8_t(ParticleKind::Boundary)) continue;
    xs.push_back(e.position[k * size_t(D)]);
    const double rho0 = e.phaseRestDensity[e.phase[k]];
    const double rho = std::max(double(e.density[k]), rho0);
    rest += 1;
    volume += rho0 / rho;
    const double c = rho / rho0 - 1;
    compression += c;
    m.maxCompressionPct = std::max(m.maxCompressionPct, 100 * c);
  }
  m.particles = xs.size();
  if (xs.empty()) return m;
  m.volumeRatio = volume / rest;
  m.avgCompressionPct = 100 * compression / rest;
  const size_t k = size_t(std::ceil(0.999 * double(xs.size()))) - 1;
  std::nth_element(xs.begin(), xs.begin() + long(k), xs.end());
  m.front = double(xs[k]) + e.particleRadius - wallX;
  return m;
}

RestingColumnMeasure measureRestingColumn(const ExportedFrames& e, const double* lo, const double* hi, double g,
                                          double settledFrom, double speedFrom) {
  const int D = e.dimension;
  const double r = e.particleRadius;
  if (e.velocity.empty() || e.pressure.empty())
    throw std::invalid_argument("the export has no velocity or pressure (a resting column is measured from both)");
  if (!(r > 0) || !(g > 0) || D < 2) throw std::invalid_argument("no particle radius, gravity or dimension");
  if (e.frames() < 2) throw std::invalid_argument("the export has no simulated frame");
  const auto liquid = [&](uint64_t k) { return e.kind[k] != uint8_t(ParticleKind::Boundary); };
  const auto topOf = [&](size_t f) {
    double top = -std::numeric_limits<double>::infinity();
    for (uint64_t k = e.offset[f]; k < e.offset[f + 1]; ++k)
      if (liquid(k)) top = std::max(top, double(e.position[k * size_t(D) + 1]));
    return top + r;
  };
  // The depth counts from the surface the liquid's volume defines (each particle a lattice cell, (2r)^D, over the
  // floor's area): no single particle's height gives it, the top row's centres ride up and down.
  double floorArea = 1, cell = 1;
  for (int d = 0; d < D; ++d) {
    cell *= 2 * r;
    if (d != 1) floorArea *= hi[d] - lo[d];
  }
  size_t liquidRows = 0;
  for (uint64_t k = e.offset[0]; k < e.offset[1]; ++k) liquidRows += liquid(k) ? 1 : 0;
  const double H = lo[1] + double(liquidRows) * cell / floorArea;
  // Interior: three diameters from the side walls, four below the surface, in up to twelve bands from the floor.
  const double interiorTop = H - 8 * r;
  const int nBands = std::min(12, int((interiorTop - lo[1]) / (2 * r)));
  if (nBands < 1) throw std::invalid_argument("the column is too shallow for an interior");
  const double bandWidth = (interiorTop - lo[1]) / nBands;

  const double top0 = topOf(0);
  RestingColumnMeasure m;
  m.closestApproach = std::numeric_limits<double>::infinity();
  std::vector<std::vector<double>> bandRatios(static_cast<size_t>(nBands));  // per band, its mean ratio in each settled frame
  size_t settled = 0, speedFrames = 0;
  for (size_t f = 1; f < e.frames(); ++f) {
    const double top = topOf(f), t = e.time[f];
    const bool inWindow = t >= settledFrom - 1e-9, timed = t >= speedFrom - 1e-9;
    double floorGap = 0, sideGap = 0, pFloor = 0, hFloor = 0;
    size_t nFloor = 0, nSide = 0;
    std::vector<double> band(static_cast<size_t>(nBands), 0.0);
    std::vector<size_t> inBand(static_cast<size_t>(nBands), 0);
    for (uint64_t k = e.offset[f]; k < e.offset[f + 1]; ++k) {
      if (!liquid(k)) continue;
      const float* x = &e.position[k * size_t(D)];
      double wallGap = std::numeric_limits<double>::infinity(), sideWall = wallGap;
      for (int d = 0; d < D; ++d) {
        const double gap = std::min(x[d] - lo[d], hi[d] - x[d]);
        wallGap = std::min(wallGap, gap);
        if (d != 1) sideWall = std::min(sideWall, gap);
      }
      m.closestApproach = std::min(m.closestApproach, wallGap / r);
      if (timed) {
        double v2 = 0;
        for (int d = 0; d < D; ++d) v2 += double(e.velocity[k * size_t(D) + d]) * e.velocity[k * size_t(D) + d];
        m.maxSpeedAfter = std::max(m.maxSpeedAfter, std::sqrt(v2));
      }
      if (!inWindow) continue;
      const double y = x[1] - lo[1];
      const double hydrostatic = e.phaseRestDensity[e.phase[k]] * g * (H - x[1]);
      if (y < 2 * r) floorGap += y / r, ++nFloor, pFloor += e.pressure[k], hFloor += hydrostatic;
      else if (y > 4 * r && x[1] < top - 4 * r && sideWall < 2 * r) sideGap += sideWall / r, ++nSide;
      if (x[1] < interiorTop && sideWall > 6 * r) {
        const size_t b = size_t(std::clamp(int(y / bandWidth), 0, nBands - 1));
        band[b] += e.pressure[k] / hydrostatic;
        ++inBand[b];
      }
    }
    if (timed) ++speedFrames;
    if (!inWindow) continue;
    ++settled;
    m.floorRowGap += nFloor ? floorGap / double(nFloor) : 0.0;
    m.sideRowGap += nSide ? sideGap / double(nSide) : 0.0;
    m.surfaceChange += (top - top0) / r;
    m.floorRowPressure += hFloor > 0 ? pFloor / hFloor : 0.0;
    for (size_t b = 0; b < band.size(); ++b)
      if (inBand[b]) bandRatios[b].push_back(band[b] / double(inBand[b]));
  }
  if (settled == 0 || speedFrames == 0)
    throw std::invalid_argument("the export ends before the settled window or the speed's start");
  const double k = 1.0 / double(settled);
  m.floorRowGap *= k, m.sideRowGap *= k, m.surfaceChange *= k, m.floorRowPressure *= k;
  for (const std::vector<double>& ratios : bandRatios) {
    if (ratios.empty()) continue;
    double mean = 0, var = 0;
    for (double v : ratios) mean += v / double(ratios.size());
    for (double v : ratios) var += (v - mean) * (v - mean);
    if (ratios.size() > 1) var /= double(ratios.size() - 1);
    m.bandPressureErrorPct = std::max(m.bandPressureErrorPct, 100 * std::abs(mean - 1));
    m.bandPressureStdPct = std::max(m.bandPressureStdPct, 100 * std::sqrt(var));
    ++m.bands;
  }
  return m;
}

std::vector<double> interpolateAt(const std::vector<double>& x, const std::vector<double>& y,
                                  const std::vector<double>& at) {
  if (x.size() != y.size() || x.size() < 2) throw std::invalid_argument("interpolation needs two or more points");
  std::vector<double> out;
  out.reserve(at.size());
  for (double a : at) {
    if (a < x.front() || a > x.back()) {
      std::ostringstream msg;
      msg << "the data covers [" << x.front() << ", " << x.back() << "], not " << a;
      throw std::invalid_argument(msg.str());
    }
    const size_t hi = size_t(std::upper_bound(x.begin(), x.end(), a) - x.begin());
    const size_t i = std::min(hi, x.size() - 1), j = i - 1;
    const double u = x[i] > x[j] ? (a - x[j]) / (x[i] - x[j]) : 0;
    out.push_back(y[j] + u * (y[i] - y[j]));
  }
  return out;
}

double surgeRms(const SurgeCurve& simulated, const SurgeCurve& reference) {
  const std::vector<double> z = interpolateAt(simulated.T, simulated.Z, reference.T);
  double sum = 0;
  for (size_t i = 0; i < z.size(); ++i) sum += (z[i] - reference.Z[i]) * (z[i] - reference.Z[i]);
  return std::sqrt(sum / double(z.size()));
}

double surgeBias(const SurgeCurve& simulated, const SurgeCurve& reference) {
  const std::vector<double> z = interpolateAt(simulated.T, simulated.Z, reference.T);
  double sum = 0;
  for (size_t i = 0; i < z.size(); ++i) sum += z[i] - reference.Z[i];
  return sum / double(z.size());
}

std::vector<bool> paretoFront(const std::vector<double>& cost, const std::vector<double>& error,
                              const std::vector<bool>& eligible) {
  const size_t n = cost.size();
  if (error.size() != n || (!eligible.empty() && eligible.size() != n))
    throw std::invalid_argument("paretoFront: cost, error and eligible differ in length");
  const auto competes = [&](size_t i) { return eligible.empty() || eligible[i]; };
  std::vector<bool> on(n, false);
  for (size_t i = 0; i < n; ++i) {
    if (!competes(i)) continue;
    bool dominated = false;
    for (size_t j = 0; j < n && !dominated; ++j)
      dominated = j != i && competes(j) && cost[j] <= cost[i] && error[j] <= error[i] &&
                  (cost[j] < cost[i] || error[j] < error[i]);
    on[i] = !dominated;
  }
  return on;
}

PresetPick pickPresets(const std::vector<double>& cost, const std::vector<double>& error,
                       const std::vector<bool>& onFront) {
  std::vector<size_t> front;
  for (size_t i = 0; i < onFront.size(); ++i)
    if (onFront[i]) front.push_back(i);
  PresetPick p;
  if (front.empty()) return p;
  // Along a front cost increases exactly when error decreases; equal points
  // (duplicates) are ordered by index so the pick is reproducible.
  std::sort(front.begin(), front.end(), [&](size_t a, size_t b) {
    return cost[a] != cost[b] ? cost[a] < cost[b] : error[a] != error[b] ? error[a] > error[b] : a < b;
  });
  p.draft = long(front.front());
  p.final = long(front.back());
  p.preview = p.final;
  // log10 of an error of 0 (a perfect point) would be -inf: floor it.
  const auto lx = [&](size_t i) { return std::log10(std::max(cost[i], 1e-12)); };
  const auto ly = [&](size_t i) { return std::log10(std::max(error[i], 1e-12)); };
  const double x0 = lx(front.front()), y0 = ly(front.front());
  const double dx = lx(front.back()) - x0, dy = ly(front.back()) - y0;
  const double len = std::hypot(dx, dy);
  double best = -std::numeric_limits<double>::infinity();
  for (size_t k = 1; k + 1 < front.size(); ++k) {
    // Distance below the chord (towards cheaper and more accurate).
    const double d = len > 0 ? ((lx(front[k]) - x0) * dy - (ly(front[k]) - y0) * dx) / len : 0;
    if (d > best) best = d, p.preview = long(front[k]);
  }
  return p;
}

}  // namespace fc
