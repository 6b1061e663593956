#pragma once
// The static solids of a scene (the domain's walls and its obstacles) as a
// volume map: Bender, Kugelstadt, Weiler & Koschier, "Volume Maps: An
// Implicit Boundary Representation for SPH", MIG 2019 [BKWK19]. A signed
// distance Φ (positive in the liquid) and, on a grid, the volume of solid in
// a particle's support weighted by how close each part is to the surface,
//   V(x) = c ∫_{|y|<h} γ(Φ(x + y)) dy,  γ(d) = 1 (d <= 0), W(d)/W(0) (0 < d < h), 0 (d >= h),
// (the map of [BKWK19]; its equation numbers could not be checked against
// the paper's text here). A particle i with 0 < Φ(x_i) < h sees one virtual
// boundary sample of volume V(x_i) at x_b = x_i - max(Φ + r/2, 2r) ∇Φ, as
// SPlisHSPlasH places it (never nearer than one particle diameter).
//
// c: SPlisHSPlasH scales by a fixed 0.8; here c is chosen so
// that a particle of the fluid lattice one radius from a flat wall has the
// rest density (its lattice neighbours plus the virtual sample), which is
// where the row against a wall should rest. The gradient sum is scaled the
// same way (gradientScale): at that particle it equals the lattice's sum of
// ∇W over the points the wall removed, so that the wall pushes as the
// missing liquid would.
//
// Density map (Options::density): the grid holds the solids' density
// contribution itself, B(x) = c ∫_{|y|<h, Φ(x+y)<=0} W(y) dy, after Koschier
// & Bender, "Density Maps for Improved SPH Boundary Handling", SCA 2017
// [KB17] (their smooth extension of the solid beyond its surface is not
// used: the indicator of the solid is), and the boundary's gradient sum is
// ∇B, the gradient of that same contribution: the density the solver holds
// and the force it pushes with come from one field. c as above.
#include "core/kernels.h"
#include "sph/pipeline.h"
#include "sph/setup.h"

#include <cstddef>
#include <vector>

namespace fc {

template <int D>
class VolumeMap {
 public:
  struct Options {
    Real spacing = 0;        // grid spacing, m (> 0)
    int quadrature = 8;      // quadrature points per support radius along an axis
#ifdef FLOWCLIP_FUZZ_LIMITS
    // Fuzz builds: ASan + UBSan at -O1 make a large map minutes long.
    size_t maxNodes = size_t(1) << 17;
    double maxEvaluations = 1 << 22;
#else
    size_t maxNodes = size_t(1) << 25;  // refused beyond (std::invalid_argument)
    // Integrating the band: its nodes near an obstacle and its distinct
    // wall-only nodes, × quadrature points, each one Φ; refused beyond
    // (about 20 s on one core at 10 ns per Φ).
    double maxEvaluations = 2e9;
#endif
    bool density = false;    // a density map (B) instead of a volume map (V)
  };
  // `latticeVolume` is the fluid lattice's volume per particle, (2r)^D.
  VolumeMap(const AABB<D>& domain, const std::vector<Obstacle<D>>& obstacles, const CubicSpline<D>& kernel,
            Real particleRadius, Real latticeVolume, const Options& options);

  // Φ(x): distance to the nearest static solid, positive in the liquid.
  Real distance(const Vec<D>& x) const;
  // The same for the domain's walls alone.
  Real wallDistance(const Vec<D>& x) const;
  // The volume map at x (interpolated), 0 beyond the support of every solid.
  Real volume(const Vec<D>& x) const;
  // Particle at x: its virtual sample's volume (0: none) and position (volume map).
  Real virtualSample(const Vec<D>& x, Vec<D>& xb) const;
  // Particle at x under gravity g: B, ∇B and the hydrostatic term (density map); false beyond reach.
  bool densityTerms(const Vec<D>& x, const Vec<D>& gravity, StaticBoundaryTerms<D>& t) const;

  Real scale() const { return scale_; }  // c
  // What the boundary's gradient sum is multiplied by, so that it matches the
  // lattice's at one radius from a flat wall as the density does (see above).
  Real gradientScale() const { return gradScale_; }
  size_t nodes() const { return values_.size(); }
  size_t integratedNodes() const { return integrated_; }
  size_t bytes() const { return values_.size() * sizeof(float); }

  // The unscaled integral at x (exact Φ, quadrature): ∫ γ(Φ(x + y)) dy, or
  // the density map's ∫_{Φ(x+y)<=0} W(y) dy.
  double integral(const Vec<D>& x) const;

 private:
  Vec<D> normal(const Vec<D>& x) const;
  size_t index(const std::array<long, D>& c) const;

  template <class Phi>
  double integrate(const Phi& phi) const;
  template <class Phi>
  double integrateDensity(const Phi& phi) const;

  AABB<D> domain_;
  std::vector<Obstacle<D>> obstacles_;
  CubicSpline<D> kernel_;
  Real r_ = 0, h_ = 0;
  Real scale_ = 1;
  Real gradScale_ = 1;
  Vec<D> origin_;
  Real spacing_ = 0, invSpacing_ = 0;
  std::array<long, D> count_{};
  std::vector<float> values_;  // c ∫γ at the grid's nodes
  std::vector<Vec<D>> offsets_;  // quadrature points y (|y| < h)
  Real cellVolume_ = 0;         // weight of each quadrature point
  size_t integrated_ = 0;
  bool density_ = false;
  Real missing_ = 0;      // B at one radius from a flat wall (what the lattice misses there)
  Real missingSamples_ = 0;  // lattice points the flat wall removes from that particle's support
  Real depth_ = 0;        // gradient-weighted mean depth of the missing lattice below that particle
};

}  // namespace fc
