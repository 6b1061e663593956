#pragma once
// Liquid particles as structure-of-arrays. Components that keep per-particle
// state of their own (solvers, effects) reorder it through reorder().
#include "core/types.h"
#include "sph/phase.h"
#include <vector>

namespace fc {

template <class T>
void applyPermutation(std::vector<T>& a, const std::vector<uint32_t>& perm, std::vector<T>& scratch) {
  if (a.size() != perm.size()) return;
  scratch.resize(a.size());
#pragma omp parallel for schedule(static)
  for (size_t k = 0; k < perm.size(); ++k) scratch[k] = a[perm[k]];
  a.swap(scratch);
}

// Hot loops read std::vector<Vec<D>> as D packed Reals per particle.
static_assert(sizeof(Vec<2>) == 2 * sizeof(Real) && sizeof(Vec<3>) == 3 * sizeof(Real));

template <int D>
struct FluidParticles {
  std::vector<Vec<D>> x;        // position, m
  std::vector<Vec<D>> v;        // velocity, m/s
  std::vector<Vec<D>> a;        // non-pressure acceleration, m/s^2
  std::vector<Real> mass;       // kg
  std::vector<Real> density;    // kg/m^3
  std::vector<Real> pressure;   // Pa (implied by the pressure solver), this substep's
  std::vector<Real> meanPressure;  // Pa: `pressure` averaged over the settings' pressure_window (what exports show)
  std::vector<uint8_t> phase;   // index into the scene's phases
  std::vector<uint8_t> kind;    // ParticleKind
  std::vector<uint32_t> id;     // stable identity across reorders

  size_t size() const { return x.size(); }
  void add(const Vec<D>& pos, const Vec<D>& vel, Real m, uint8_t ph, ParticleKind k = ParticleKind::Liquid) {
    x.push_back(pos);
    v.push_back(vel);
    a.push_back(Vec<D>::Zero());
    mass.push_back(m);
    density.push_back(0);
    pressure.push_back(0);
    meanPressure.push_back(0);
    phase.push_back(ph);
    kind.push_back(uint8_t(k));
    id.push_back(uint32_t(id.size()));
  }
  void truncate(size_t n) {
    x.resize(n);
    v.resize(n);
    a.resize(n);
    mass.resize(n);
    density.resize(n);
    pressure.resize(n);
    meanPressure.resize(n);
    phase.resize(n);
    kind.resize(n);
    id.resize(n);
  }
  // Scratch arrays kept between reorders, so that reordering allocates
  // nothing once they have grown.
  struct Scratch {
    std::vector<Vec<D>> sv;
    std::vector<Real> sr;
    std::vector<uint8_t> s8;
    std::vector<uint32_t> s32;
  };
  void reorder(const std::vector<uint32_t>& perm, Scratch& scratch) {
    auto& [sv, sr, s8, s32] = scratch;
    applyPermutation(x, perm, sv);
    applyPermutation(v, perm, sv);
    applyPermutation(a, perm, sv);
    applyPermutation(mass, perm, sr);
    applyPermutation(density, perm, sr);
    applyPermutation(pressure, perm, sr);
    applyPermutation(meanPressure, perm, sr);
    applyPermutation(phase, perm, s8);
    applyPermutation(kind, perm, s8);
    applyPermutation(id, perm, s32);
  }
};

// Boundary particles (Akinci et al. 2012 [AIA*12]): each samples a solid surface and
// carries the volume it represents, so that Ψ_b = ρ0 V_b enters density and
// pressure sums like a fluid mass.
template <int D>
struct BoundaryParticles {
  std::vector<Vec<D>> x;
  std::vector<Vec<D>> v;       // zero for static solids
  std::vector<Real> volume;    // m^3 (m^2 in 2D)
  size_t size() const { return x.size(); }
};

}  // namespace fc
