#pragma once
// SPH smoothing kernels in 2D and 3D, normalised so that ∫W dV = 1 over the
// support ball of radius h (the support radius, not the smoothing length).
#include "core/types.h"
#include <algorithm>
#include <cmath>
#include <numbers>

namespace fc {

// Cubic spline (Monaghan 1992 [Mon92]) written with support radius h, as in
// SPlisHSPlasH: q = r/h in [0,1], W = k (6q^3 - 6q^2 + 1) for q <= 1/2,
// W = k 2 (1-q)^3 for q <= 1, where k = 40/(7 pi h^2) in 2D and 8/(pi h^3) in 3D.
template <int D>
class CubicSpline {
 public:
  CubicSpline() : CubicSpline(Real(1)) {}
  explicit CubicSpline(Real h) { setRadius(h); }

  void setRadius(Real h) {
    h_ = h;
    invH_ = Real(1) / h;
    const double pi = std::numbers::pi;
    if constexpr (D == 2) {
      k_ = Real(40.0 / (7.0 * pi * double(h) * double(h)));
      l_ = Real(240.0 / (7.0 * pi * double(h) * double(h)));
    } else {
      k_ = Real(8.0 / (pi * double(h) * double(h) * double(h)));
      l_ = Real(48.0 / (pi * double(h) * double(h) * double(h)));
    }
    w0_ = k_;
  }
  Real radius() const { return h_; }
  Real W0() const { return w0_; }

  Real W(Real r) const {
    const Real q = r * invH_;
    if (q > Real(1)) return 0;
    if (q <= Real(0.5)) {
      const Real q2 = q * q;
      return k_ * (Real(6) * q2 * q - Real(6) * q2 + Real(1));
    }
    const Real f = Real(1) - q;
    return k_ * Real(2) * f * f * f;
  }
  Real W(const Vec<D>& r) const { return W(r.norm()); }

  // W and ∇W together (one square root), r = x_i - x_j.
  void evaluate(const Vec<D>& r, Real& w, Vec<D>& grad) const {
    const Real rl = r.norm();
    const Real q = rl * invH_;
    if (q > Real(1)) {
      w = 0;
      grad.setZero();
      return;
    }
    const Real scale = rl > Real(1e-9) * h_ ? invH_ / rl : Real(0);
    if (q <= Real(0.5)) {
      const Real q2 = q * q;
      w = k_ * (Real(6) * q2 * q - Real(6) * q2 + Real(1));
      grad = (l_ * q * (Real(3) * q - Real(2)) * scale) * r;
    } else {
      const Real f = Real(1) - q;
      w = k_ * Real(2) * f * f * f;
      grad = (l_ * (-f * f) * scale) * r;
    }
  }

  // Branch-free form for vectorised loops: from |r|², W and the factor F
  // with ∇W = F r. Zero outside the support and at r = 0.
  void evaluateSquared(Real r2, Real& w, Real& f) const {
    const Real rl = std::sqrt(r2);
    const Real q = rl * invH_;
    const Real g = Real(1) - q;
    const Real inner = k_ * (Real(6) * q * q * q - Real(6) * q * q + Real(1));
    const Real outer = k_ * Real(2) * g * g * g;
    const Real dInner = l_ * q * (Real(3) * q - Real(2));
    const Real dOuter = -l_ * g * g;
    const bool in = q <= Real(1);
    const bool near = q <= Real(0.5);
    w = in ? (near ? inner : outer) : Real(0);
    const Real scale = invH_ / std::max(rl, Real(1e-9) * h_);
    f = (in && rl > Real(1e-9) * h_) ? (near ? dInner : dOuter) * scale : Real(0);
  }

  // ∇W(r) with r = x_i - x_j.
  Vec<D> gradW(const Vec<D>& r) const {
    const Real rl = r.norm();
    const Real q = rl * invH_;
    if (q > Real(1) || rl <= Real(1e-9) * h_) return Vec<D>::Zero();
    const Vec<D> gradq = r * (invH_ / rl);
    if (q <= Real(0.5)) return l_ * q * (Real(3) * q - Real(2)) * gradq;
    const Real f = Real(1) - q;
    return l_ * (-f * f) * gradq;
  }

 private:
  Real h_ = 1, invH_ = 1, k_ = 0, l_ = 0, w0_ = 0;
};

// Poly6 (Müller et al. 2003 [MCG03]), used by template control (paper eq. 3):
// W = k (h^2 - r^2)^3 with k = 4/(pi h^8) in 2D and 315/(64 pi h^9) in 3D.
template <int D>
class Poly6 {
 public:
  Poly6() : Poly6(Real(1)) {}
  explicit Poly6(Real h) { setRadius(h); }
  void setRadius(Real h) {
    h_ = h;
    h2_ = h * h;
    const double pi = std::numbers::pi;
    const double hd = h;
    if constexpr (D == 2) k_ = Real(4.0 / (pi * std::pow(hd, 8)));
    else k_ = Real(315.0 / (64.0 * pi * std::pow(hd, 9)));
  }
  Real radius() const { return h_; }
  Real W0() const { return k_ * h2_ * h2_ * h2_; }
  // W = coefficient · (h² − r²)³ inside the support (for vectorised loops).
  Real coefficient() const { return k_; }
  Real W2(Real r2) const {
    if (r2 >= h2_) return 0;
    const Real d = h2_ - r2;
    return k_ * d * d * d;
  }
  Real W(Real r) const { return W2(r * r); }
  Real W(const Vec<D>& r) const { return W2(r.squaredNorm()); }
  // ∇W = -6 k (h^2 - r^2)^2 r
  Vec<D> gradW(const Vec<D>& r) const {
    const Real r2 = r.squaredNorm();
    if (r2 >= h2_) return Vec<D>::Zero();
    const Real d = h2_ - r2;
    return Real(-6) * k_ * d * d * r;
  }

 private:
  Real h_ = 1, h2_ = 1, k_ = 0;
};

// Cohesion kernel of Akinci, Akinci & Teschner 2013 ("Versatile Surface
// Tension and Adhesion for SPH Fluids", [AAT13], eq. (2)), support radius h:
//   C(r) = k (h-r)^3 r^3                   for h/2 < r <= h,
//   C(r) = k (2 (h-r)^3 r^3 - h^6/64)      for 0 < r <= h/2,
// attractive above r = 0.2729 h, repulsive below (particles clumping closer
// than about half a spacing push apart). 3D: k = 32 / (pi h^9), the paper's.
// 2D: k = (4704/605) / h^8 (7.775 / h^8, not 32/(pi h^8) = 10.19 / h^8),
// derived so that the cohesion force gives the same continuum surface tension
// in 2D and 3D for the same gamma, density and h. For a pair force
// -u'(r) x^ between two half-spaces of density rho, splitting them costs
// 2 sigma = c_D/(D+1) rho^2/m^2 Integral u'(r) r^(D+1) dr per interface area,
// with c_3 = pi and c_2 = 2 (the integral of cos(theta) over the half sphere,
// half circle); with u' = gamma m_i m_j C(r) this is
//   3D: sigma = (pi/8) gamma rho^2 Integral C r^4 dr = (21/7040) gamma rho^2 h^2,
//   2D: sigma = (1/3)  gamma rho^2 Integral C r^3 dr = (11/28672) k h^10 gamma rho^2,
// (exact polynomial integrals), equal when k h^8 = (21/7040)(28672/11) = 4704/605.
// sigmaPerGammaRho2H2() returns 21/7040 in both (tests integrate it).
template <int D>
class CohesionKernel {
 public:
  CohesionKernel() : CohesionKernel(Real(1)) {}
  explicit CohesionKernel(Real h) { setRadius(h); }
  void setRadius(Real h) {
    h_ = h;
    const double hd = h;
    if constexpr (D == 2) k_ = Real(4704.0 / 605.0 / std::pow(hd, 8));
    else k_ = Real(32.0 / (std::numbers::pi * std::pow(hd, 9)));
    c_ = Real(std::pow(hd, 6) / 64.0);
  }
  Real radius() const { return h_; }
  static constexpr double sigmaPerGammaRho2H2() { return 21.0 / 7040.0; }
  // r = |x_i - x_j|; branch-free (vectorised loops).
  Real W(Real r) const {
    const Real g = h_ - r;
    const Real outer = g * g * g * r * r * r;
    const Real inner = Real(2) * outer - c_;
    return r <= h_ ? k_ * (r > Real(0.5) * h_ ? outer : inner) : Real(0);
  }

 private:
  Real h_ = 1, k_ = 0, c_ = 0;
};

// Adhesion kernel of [AAT13], eq. (7), support radius h:
//   A(r) = k (-4 r^2/h + 6 r - 2 h)^(1/4)  for h/2 < r <= h, else 0.
// 3D: k = 0.007 / h^3.25, the paper's. 2D: k = 0.0067337 / h^2.25, from the
// same argument as the cohesion kernel (equal work of adhesion per interface
// area in 2D and 3D for the same beta): k2 h^2.25 = 0.007 (3 pi/8) I4 / I3
// with Iq = Integral_{1/2}^{1} (-4s^2 + 6s - 2)^(1/4) s^q ds (I4 = 0.116585,
// I3 = 0.142780, numerically).
template <int D>
class AdhesionKernel {
 public:
  AdhesionKernel() : AdhesionKernel(Real(1)) {}
  explicit AdhesionKernel(Real h) { setRadius(h); }
  void setRadius(Real h) {
    h_ = h;
    k_ = Real((D == 2 ? 0.0067337027 : 0.007) / std::pow(double(h), D + 0.25));
  }
  Real radius() const { return h_; }
  Real W(Real r) const {
    if (!(r > Real(0.5) * h_ && r <= h_)) return 0;
    const Real p = std::max(Real(0), -Real(4) * r * r / h_ + Real(6) * r - Real(2) * h_);
    return k_ * std::sqrt(std::sqrt(p));
  }

 private:
  Real h_ = 1, k_ = 0;
};

// Every point of a lattice of spacing s within the cube ±⌈h/s⌉ s about a
// particle of it: `visit` gets the point's offset from the particle.
template <int D, class Visit>
void forEachLatticeOffset(const CubicSpline<D>& kernel, Real s, Visit&& visit) {
  const int n = int(std::ceil(kernel.radius() / s));
  VecI<D> k = VecI<D>::Constant(-n);
  while (true) {
    visit(Vec<D>(s * k.template cast<Real>()));
    int d = 0;
    while (d < D && ++k[d] > n) k[d++] = -n;
    if (d == D) break;
  }
}

// The volume a particle of the initial lattice (spacing s) stands for, such
// that the lattice has exactly the rest density: 1 / Σ_k W(k s). It differs
// from s^D by the discretisation error of the kernel sum (+0.09 % in 2D with
// h = 2s, which would start every 2D liquid compressed beyond the default
// tolerance).
template <int D>
Real latticeParticleVolume(const CubicSpline<D>& kernel, Real s) {
  double sum = 0;
  forEachLatticeOffset<D>(kernel, s, [&](const Vec<D>& p) { sum += kernel.W(p); });
  return Real(1.0 / sum);
}

// A particle of that lattice one radius (s/2) from a flat wall, the wall
// along its rows (normal y): the wall takes the rows below the particle's
// own. What it takes from its density, 1 - V Σ W over the points on its
// side (V the lattice volume): the solids' Σ_b V_b W_ib that gives it the
// rest density.
template <int D>
double flatWallMissingVolume(const CubicSpline<D>& kernel, Real s, Real latticeVolume) {
  double sum = 0;
  forEachLatticeOffset<D>(kernel, s, [&](const Vec<D>& p) {
    if (p[1] >= 0) sum += double(kernel.W(p));
  });
  return 1.0 - double(latticeVolume) * sum;
}

// The push the removed points gave it, along the wall's normal: V Σ ∂W/∂y
// of its offset from each of them.
template <int D>
double flatWallMissingPush(const CubicSpline<D>& kernel, Real s, Real latticeVolume) {
  double sum = 0;
  forEachLatticeOffset<D>(kernel, s, [&](const Vec<D>& p) {
    if (p[1] >= 0) return;
    Real w;
    Vec<D> g;
    kernel.evaluate(Vec<D>(-p), w, g);
    sum += double(g[1]);
  });
  return double(latticeVolume) * sum;
}

}  // namespace fc
