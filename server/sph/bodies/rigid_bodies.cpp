#include "sph/bodies/rigid_bodies.h"

#include "core/transform.h"
#include "sph/sampling/boundary.h"
#include "sph/simulation.h"
#include "core/neighborhood_search.h"
#include <omp.h>
#include <algorithm>
#include <cmath>
#include <numbers>

namespace fc {

namespace {
constexpr double kDeg = std::numbers::pi / 180.0;

template <int D>
using VecDd = Eigen::Matrix<double, D, 1>;

// ω × r: 2D ω is a scalar about z.
inline Eigen::Vector2d crossWR(const Eigen::Matrix<double, 1, 1>& w, const Eigen::Vector2d& r) {
  return w[0] * Eigen::Vector2d(-r.y(), r.x());
}
inline Eigen::Vector3d crossWR(const Eigen::Vector3d& w, const Eigen::Vector3d& r) { return w.cross(r); }
// r × F: 2D the z component.
inline Eigen::Matrix<double, 1, 1> crossRF(const Eigen::Vector2d& r, const Eigen::Vector2d& f) {
  return Eigen::Matrix<double, 1, 1>(r.x() * f.y() - r.y() * f.x());
}
inline Eigen::Vector3d crossRF(const Eigen::Vector3d& r, const Eigen::Vector3d& f) { return r.cross(f); }


}  // namespace

template <int D>
typename RigidBodies<D>::VecD RigidBodies<D>::State::pointVelocity(const VecD& x) const {
  return velocity + crossWR(angularVelocity, VecD(x - centre));
}

template <int D>
Real RigidBodies<D>::State::signedDistance(const Vec<D>& x) const {
  const VecD local = rotation.transpose() * (x.template cast<double>() - centre);
  return spec.localSignedDistance(local.template cast<Real>());
}

template <int D>
RigidBodies<D>::RigidBodies(const std::vector<Body<D>>& bodies, Real radius, int layers, const CubicSpline<D>& kernel,
                            Real latticeVolume, BoundaryParticles<D>& boundary, const Vec<D>& gravity) {
  gravity_ = gravity.template cast<double>();
  firstBody_ = boundary.size();
  const Real spacing = 2 * radius;
  for (size_t k = 0; k < bodies.size(); ++k) {
    State s;
    s.spec = bodies[k];
    const Body<D>& b = s.spec;
    // Samples one particle radius inside the surface, `layers` deep, as for obstacles.
    if (b.shape == ObstacleShape::Box)
      sampleBoxShell<D>(AABB<D>(Vec<D>(-b.halfSize.array() + radius), Vec<D>(b.halfSize.array() - radius)), spacing,
                        layers, false, s.local);
    else
      sampleSphereShell<D>(Vec<D>::Zero(), b.radius - radius, spacing, layers, s.local);
    s.first = boundary.size();
    s.count = s.local.size();
    // Mass and inertia of the solid shape (2D: per metre of depth).
    const double rho = double(b.density);
    if (b.shape == ObstacleShape::Box) {
      const VecD e = 2 * b.halfSize.template cast<double>();
      double vol = 1;
      for (int d = 0; d < D; ++d) vol *= e[d];
      s.mass = rho * vol;
      if constexpr (D == 2) {
        s.inertia(0, 0) = s.mass * (e[0] * e[0] + e[1] * e[1]) / 12;
      } else {
        s.inertia = Eigen::Matrix3d::Zero();
        s.inertia(0, 0) = s.mass * (e[1] * e[1] + e[2] * e[2]) / 12;
        s.inertia(1, 1) = s.mass * (e[0] * e[0] + e[2] * e[2]) / 12;
        s.inertia(2, 2) = s.mass * (e[0] * e[0] + e[1] * e[1]) / 12;
      }
    } else {
      const double r = double(b.radius);
      if constexpr (D == 2) {
        s.mass = rho * std::numbers::pi * r * r;
        s.inertia(0, 0) = 0.5 * s.mass * r * r;
      } else {
        s.mass = rho * 4.0 / 3.0 * std::numbers::pi * r * r * r;
        s.inertia = Eigen::Matrix3d::Identity() * (0.4 * s.mass * r * r);
      }
    }
    s.centre = b.position.template cast<double>();
    if constexpr (D == 2) {
      s.angle = b.rotationDeg[0] * kDeg;
    } else {
      s.orientation = eulerXYZDegrees(b.rotationDeg);
    }
    dynamic_ = dynamic_ || b.motion == BodyMotion::Dynamic;
    if (b.motion == BodyMotion::Dynamic) s.velocity = b.velocity.template cast<double>();
    // Volumes from the body's own samples (its shape does not change).
    std::vector<Real> volume(s.count);
    {
      AABB<D> box;
      for (const Vec<D>& q : s.local) box.extend(q);
      NeighborhoodSearch<D> grid;
      grid.setGrid(box.grown(kernel.radius()), kernel.radius());
      grid.setStaticPoints(s.local);
#pragma omp parallel for schedule(static)
      for (size_t i = 0; i < s.count; ++i) {
        Real sum = 0;
        grid.forEachStaticNear(s.local[i], kernel.radius(),
                               [&](uint32_t, const Vec<D>& q) { sum += kernel.W(Vec<D>(s.local[i] - q)); });
        volume[i] = sum > 0 ? std::min(latticeVolume, Real(1) / sum) : latticeVolume;
      }
    }
    for (size_t i = 0; i < s.count; ++i) {
      boundary.x.push_back(Vec<D>::Zero());
      boundary.v.push_back(Vec<D>::Zero());
      boundary.volume.push_back(volume[i]);
      owner_.push_back(int(k));
    }
    bodies_.push_back(std::move(s));
  }
  for (State& s : bodies_) poseAt(s, 0);
  place(0, boundary);
}

// The pose of a kinematic body at `time` (dynamic ones keep their state).
template <int D>
void RigidBodies<D>::poseAt(State& s, double time) const {
  const Body<D>& b = s.spec;
  if (b.motion == BodyMotion::Dynamic) return;
  time += timeOffset_;
  if (!b.keys.empty()) {
    double t = time;
    if (b.period > 0) t = std::fmod(time, b.period);
    const auto& keys = b.keys;
    size_t i = 0;
    while (i + 1 < keys.size() && keys[i + 1].time <= t) ++i;
    const BodyKey<D>& k0 = keys[i];
    const bool hold = i + 1 >= keys.size() || t < keys.front().time;
    const BodyKey<D>& k1 = hold ? k0 : keys[i + 1];
    const double span = k1.time - k0.time;
    const double u = hold || span <= 0 ? 0.0 : std::clamp((t - k0.time) / span, 0.0, 1.0);
    const VecD p0 = k0.position.template cast<double>(), p1 = k1.position.template cast<double>();
    s.centre = p0 + u * (p1 - p0);
    s.velocity = hold || span <= 0 ? VecD::Zero() : VecD((p1 - p0) / span);
    if constexpr (D == 2) {
      const double a0 = k0.rotationDeg[0] * kDeg, a1 = k1.rotationDeg[0] * kDeg;
      s.angle = a0 + u * (a1 - a0);
      s.angularVelocity[0] = hold || span <= 0 ? 0.0 : (a1 - a0) / span;
    } else {
      const Eigen::Quaterniond q0 = eulerXYZDegrees(k0.rotationDeg), q1 = eulerXYZDegrees(k1.rotationDeg);
      s.orientation = q0.slerp(u, q1);
      const Eigen::AngleAxisd delta(q1 * q0.conjugate());
      s.angularVelocity = hold || span <= 0 ? Ang::Zero() : Ang(delta.axis() * (delta.angle() / span));
    }
  } else {
    s.centre = b.position.template cast<double>() + time * b.velocity.template cast<double>();
    s.velocity = b.velocity.template cast<double>();
    if constexpr (D == 2) {
      s.angularVelocity[0] = b.angularVelocityDeg[0] * kDeg;
      s.angle = b.rotationDeg[0] * kDeg + time * s.angularVelocity[0];
    } else {
      const Eigen::Vector3d w(b.angularVelocityDeg[0] * kDeg, b.angularVelocityDeg[1] * kDeg,
                              b.angularVelocityDeg[2] * kDeg);
      s.angularVelocity = w;
      const double wn = w.norm();
      const Eigen::Quaterniond q0 = eulerXYZDegrees(b.rotationDeg);
      s.orientation = wn > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(wn * time, w / wn)) * q0 : q0;
    }
  }
}

template <int D>
void RigidBodies<D>::place(double time, BoundaryParticles<D>& boundary) {
  for (State& s : bodies_) {
    poseAt(s, time);
    if constexpr (D == 2) {
      s.rotation = Eigen::Rotation2Dd(s.angle).toRotationMatrix();
    } else {
      s.orientation.normalize();
      s.rotation = s.orientation.toRotationMatrix();
    }
    const long n = long(s.count);
#pragma omp parallel for schedule(static) if (n > 4096)
    for (long i = 0; i < n; ++i) {
      const VecD r = s.rotation * s.local[size_t(i)].template cast<double>();
      boundary.x[s.first + size_t(i)] = (s.centre + r).template cast<Real>();
      boundary.v[s.first + size_t(i)] = (s.velocity + crossWR(s.angularVelocity, r)).template cast<Real>();
    }
  }
}

template <int D>
void RigidBodies<D>::integrate(const Simulation<D>& sim, Real dt, const AABB<D>& domain, Real radius) {
  if (!dynamic_) return;
  const auto& f = sim.fluid;
  const auto& boundary = sim.boundary;
  const size_t nb = bodies_.size();
  const long n = long(f.size());
  const Real h = sim.supportRadius();
  const Real weight = sim.boundaryPressureWeight();
  const bool extrapolated = !sim.boundaryExtrapolation.empty();
  // The pressure force of the liquid on each boundary particle b of a
  // dynamic body, the reaction of the one the particle exerts on the liquid:
  // F_b = m_i Ψ_b (w p_i / ρ_i²) ∇W_ib, Ψ_b = ρ0_i V_b ([AIA*12], Sec. 4; w
  // the boundary model's weight, pipeline.h).
  // Summed per fixed block of particles, then the blocks in order: the
  // bodies' motion must not depend on how many threads split the liquid.
  const size_t stride = nb * size_t(D + A);
  const long blocks = clearBlockSums(size_t(n));
#pragma omp parallel for schedule(static)
  for (long blk = 0; blk < blocks; ++blk) {
    double* local = blockSums_.data() + size_t(blk) * stride;
    Real w;
    Vec<D> g;
    for (long i = blk * kBlock; i < std::min(n, (blk + 1) * kBlock); ++i) {
      const bool pressed = f.pressure[size_t(i)] > 0;
      if (sim.boundaryNeighbors[size_t(i)] == 0 || !(pressed || extrapolated)) continue;
      const Vec<D> xi = f.x[size_t(i)];
      const Real rho = f.density[size_t(i)];
      const double scale = pressed ? double(f.mass[size_t(i)]) * double(sim.restDensity(size_t(i))) *
                                         double(weight * f.pressure[size_t(i)] / (rho * rho))
                                   : 0.0;
      sim.search.forEachStaticNear(xi, h, [&](uint32_t b, const Vec<D>& xb) {
        const int k = owner(b);
        if (k < 0 || bodies_[size_t(k)].spec.motion != BodyMotion::Dynamic) return;
        sim.kernel.evaluate(Vec<D>(xi - xb), w, g);
        // Plus the sample's extrapolated pressure, m_i V_b (g·(x_b - x_i)) ∇W_ib (sph/boundary/adami2012.cpp).
        const double hydro = extrapolated ? double(f.mass[size_t(i)]) * gravity_.dot(Vec<D>(xb - xi).template cast<double>()) : 0.0;
        const VecD F = ((scale + hydro) * double(boundary.volume[b])) * g.template cast<double>();
        const VecD r = xb.template cast<double>() - bodies_[size_t(k)].centre;
        const Ang tq = crossRF(r, F);
        double* o = local + size_t(k) * size_t(D + A);
        for (int d = 0; d < D; ++d) o[d] += F[d];
        for (int a = 0; a < A; ++a) o[D + a] += tq[a];
      });
    }
  }
  std::vector<double>& acc = blockTotal_;
  acc.assign(stride, 0.0);
  for (long blk = 0; blk < blocks; ++blk)
    for (size_t k = 0; k < stride; ++k) acc[k] += blockSums_[size_t(blk) * stride + k];

  const double step = double(dt);
  for (size_t k = 0; k < nb; ++k) {
    State& s = bodies_[k];
    if (s.spec.motion != BodyMotion::Dynamic) continue;
    for (int d = 0; d < D; ++d) s.force[d] = acc[k * size_t(D + A) + size_t(d)];
    for (int a = 0; a < A; ++a) s.torque[a] = acc[k * size_t(D + A) + size_t(D + a)];
    // Semi-implicit Euler: velocities from forces (and the contacts'
    // impulses), then the pose from the new velocities.
    s.velocity += step * (s.force / s.mass + gravity_) + s.contactImpulse / s.mass;
    if constexpr (D == 2) {
      s.angularVelocity[0] += (step * s.torque[0] + s.contactAngularImpulse[0]) / s.inertia(0, 0);
      s.angle += step * s.angularVelocity[0];
      s.rotation = Eigen::Rotation2Dd(s.angle).toRotationMatrix();
    } else {
      const Eigen::Matrix3d R = s.rotation;
      const Eigen::Matrix3d Iw = R * s.inertia * R.transpose();
      const Eigen::Matrix3d IwInv = R * s.inertia.inverse() * R.transpose();
      const Eigen::Vector3d w = s.angularVelocity;
      s.angularVelocity += IwInv * (step * (s.torque - w.cross(Iw * w)) + s.contactAngularImpulse);
      const Eigen::Vector3d wn = s.angularVelocity;
      Eigen::Quaterniond dq(0, wn.x(), wn.y(), wn.z());
      dq = dq * s.orientation;
      s.orientation.coeffs() += 0.5 * step * dq.coeffs();
      s.orientation.normalize();
      s.rotation = s.orientation.toRotationMatrix();
    }
    s.centre += step * s.velocity;
    s.contactImpulse.setZero();
    s.contactAngularImpulse.setZero();

    // Tank walls: the body's samples stay a particle radius inside the
    // domain (its surface then touches the wall). The deepest sample per
    // wall is pushed back and gets an inelastic impulse along the normal.
    bool touched = false;
    for (int d = 0; d < D; ++d)
      for (int side = 0; side < 2; ++side) {
        double deepest = 0;
        const double wall = side == 0 ? double(domain.min[d] + radius) : double(domain.max[d] - radius);
        auto penetration = [&](const Vec<D>& p) {
          const VecD x = s.centre + s.rotation * p.template cast<double>();
          return side == 0 ? wall - x[d] : x[d] - wall;
        };
        for (const Vec<D>& p : s.local) deepest = std::max(deepest, penetration(p));
        if (deepest <= 0) continue;
        // The contact point: the centroid of the samples within a tenth of a
        // radius of the deepest (a face resting flat is hit at its middle,
        // not at one corner, which would spin it).
        VecD at = VecD::Zero();
        int hits = 0;
        for (const Vec<D>& p : s.local)
          if (penetration(p) >= deepest - 0.1 * double(radius)) {
            at += s.centre + s.rotation * p.template cast<double>();
            ++hits;
          }
        at /= double(hits);
        touched = true;
        VecD nrm = VecD::Zero();
        nrm[d] = side == 0 ? 1.0 : -1.0;
        s.centre += deepest * nrm;
        at += deepest * nrm;
        const VecD r = at - s.centre;
        const double vn = s.pointVelocity(at).dot(nrm);
        if (vn >= 0) continue;
        const Eigen::Matrix<double, A, A> Iinv =
            D == 2 ? Eigen::Matrix<double, A, A>(s.inertia.inverse())
                   : Eigen::Matrix<double, A, A>(s.rotation.template topLeftCorner<A, A>() * s.inertia.inverse() *
                                                 s.rotation.template topLeftCorner<A, A>().transpose());
        const Ang rn = crossRF(r, nrm);
        const VecD angular = crossWR(Ang(Iinv * rn), r);
        const double j = -vn / (1.0 / s.mass + nrm.dot(angular));
        s.velocity += (j / s.mass) * nrm;
        s.angularVelocity += Iinv * crossRF(r, VecD(j * nrm));
      }
    if (touched) ++s.wallContacts;
  }
}

template <int D>
long RigidBodies<D>::clearBlockSums(size_t particles) {
  const long blocks = (long(particles) + kBlock - 1) / kBlock;
  const size_t size = size_t(blocks) * bodies_.size() * size_t(D + A);
  if (blockSums_.size() < size) blockSums_.resize(size);
  std::fill(blockSums_.begin(), blockSums_.begin() + long(size), 0.0);
  return blocks;
}

template <int D>
void RigidBodies<D>::beginContacts(size_t particles) { contactBlocks_ = clearBlockSums(particles); }

template <int D>
void RigidBodies<D>::endContacts() {
  const size_t stride = bodies_.size() * size_t(D + A);
  for (long blk = 0; blk < contactBlocks_; ++blk)
    for (size_t k = 0; k < bodies_.size(); ++k) {
      const double* o = blockSums_.data() + size_t(blk) * stride + k * size_t(D + A);
      State& s = bodies_[k];
      for (int d = 0; d < D; ++d) s.contactImpulse[d] += o[d];
      for (int a = 0; a < A; ++a) s.contactAngularImpulse[a] += o[D + a];
    }
}

template <int D>
void RigidBodies<D>::contact(Vec<D>& x, Vec<D>& v, Real mass, Real distance, bool& touched, bool& crossed,
                             size_t particle) {
  size_t k = 0;
  for (State& s : bodies_) {
    const size_t body = k++;
    const VecD xd = x.template cast<double>();
    const double reach = double(s.spec.boundingRadius() + distance);
    if ((xd - s.centre).squaredNorm() > reach * reach) continue;
    const VecD local = s.rotation.transpose() * (xd - s.centre);
    const Real sd = s.spec.localSignedDistance(local.template cast<Real>());
    if (sd >= distance) continue;
    crossed = crossed || sd < 0;
    touched = true;
    // Outward normal from the distance's gradient (body frame).
    VecD g;
    const double eps = 1e-4 * double(distance > 0 ? distance : Real(1e-3));
    for (int d = 0; d < D; ++d) {
      VecD e = VecD::Zero();
      e[d] = eps;
      g[d] = double(s.spec.localSignedDistance((local + e).template cast<Real>()) -
                    s.spec.localSignedDistance((local - e).template cast<Real>()));
    }
    if (!(g.norm() > 0)) continue;
    const VecD nrm = s.rotation * g.normalized();
    const VecD moved = xd + double(distance - sd) * nrm;
    x = moved.template cast<Real>();
    const VecD vb = s.pointVelocity(moved);
    const double vn = (v.template cast<double>() - vb).dot(nrm);
    if (vn < 0) {
      v = (v.template cast<double>() - vn * nrm).template cast<Real>();
      if (s.spec.motion == BodyMotion::Dynamic) {
        // The momentum the liquid loses goes into the body.
        const VecD J = double(mass) * vn * nrm;
        const Ang L = crossRF(VecD(moved - s.centre), J);
        // This particle's block (one thread per block: beginContacts).
        double* o = blockSums_.data() + (particle / size_t(kBlock) * bodies_.size() + body) * size_t(D + A);
        for (int d = 0; d < D; ++d) o[d] += J[d];
        for (int a = 0; a < A; ++a) o[D + a] += L[a];
      }
    }
  }
}

template <int D>
void RigidBodies<D>::continueFrom(const RigidBodies& old, double timeOffset) {
  timeOffset_ = timeOffset;
  for (State& s : bodies_) {
    if (s.spec.motion != BodyMotion::Dynamic) continue;
    for (const State& o : old.bodies_)
      if (o.spec.name == s.spec.name && o.spec.motion == BodyMotion::Dynamic) {
        s.centre = o.centre;
        s.velocity = o.velocity;
        s.angle = o.angle;
        s.orientation = o.orientation;
        s.rotation = o.rotation;
        s.angularVelocity = o.angularVelocity;
        s.contactImpulse = o.contactImpulse;
        s.contactAngularImpulse = o.contactAngularImpulse;
      }
  }
}

template <int D>
void RigidBodies<D>::archiveState(StateArchive& a) {
  a.section("bodies");
  uint64_t n = bodies_.size();
  a.io(n);
  if (n != bodies_.size())
    throw StateArchiveError("checkpoint holds " + std::to_string(n) + " bodies, the scene " +
                            std::to_string(bodies_.size()));
  for (State& s : bodies_) {
    a.io(s.centre);
    a.io(s.velocity);
    a.io(s.rotation);
    a.io(s.orientation.coeffs());
    a.io(s.angle);
    a.io(s.angularVelocity);
    a.io(s.force);
    a.io(s.torque);
    a.io(s.contactImpulse);
    a.io(s.contactAngularImpulse);
    a.io(s.wallContacts);
  }
  a.io(timeOffset_);
}

template <int D>
bool RigidBodies<D>::finite() const {
  for (const State& s : bodies_)
    if (!s.centre.allFinite() || !s.velocity.allFinite() || !s.angularVelocity.allFinite() || !s.rotation.allFinite())
      return false;
  return true;
}

template <int D>
bool RigidBodies<D>::inside(const Vec<D>& x) const {
  for (const State& s : bodies_)
    if (s.signedDistance(x) < 0) return true;
  return false;
}

template <int D>
double RigidBodies<D>::maxPointSpeed() const {
  double v = 0;
  for (const State& s : bodies_) v = std::max(v, s.velocity.norm() + s.angularVelocity.norm() * double(s.spec.boundingRadius()));
  return v;
}

template <int D>
void RigidBodies<D>::reportFrame(FrameStats& fs) {
  fs.bodies.clear();
  for (State& s : bodies_) {
    BodyFrameStats b;
    b.name = s.spec.name;
    for (int d = 0; d < D; ++d) {
      b.position[size_t(d)] = s.centre[d];
      b.velocity[size_t(d)] = s.velocity[d];
    }
    if constexpr (D == 2) {
      b.rotationDeg[2] = s.angle / kDeg;
    } else {
      // Euler XYZ of R = Rx(a) Ry(b) Rz(c), b in [-90°, 90°] (the identity is 0, 0, 0).
      const Eigen::Matrix3d& R = s.rotation;
      b.rotationDeg[0] = std::atan2(-R(1, 2), R(2, 2)) / kDeg;
      b.rotationDeg[1] = std::asin(std::clamp(R(0, 2), -1.0, 1.0)) / kDeg;
      b.rotationDeg[2] = std::atan2(-R(0, 1), R(0, 0)) / kDeg;
    }
    for (int d = 0; d < D; ++d) b.force[size_t(d)] = s.force[d];
    b.wallContacts = s.wallContacts;
    s.wallContacts = 0;
    fs.bodies.push_back(b);
  }
}

template class RigidBodies<2>;
template class RigidBodies<3>;

}  // namespace fc
