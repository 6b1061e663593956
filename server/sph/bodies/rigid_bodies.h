#pragma once
// Moving solids: kinematic bodies (their motion is given: keys or constant
// velocities) and dynamic rigid bodies two-way coupled with the liquid as in
// Akinci et al. 2012 ("Versatile Rigid-Fluid Coupling for Incompressible
// SPH", [AIA*12]): each body is sampled with boundary particles that enter
// the liquid's density and pressure sums like the walls do, moving with the
// body; the pressure force the liquid exerts on those particles, plus
// gravity, drives a dynamic body, whose new velocity moves the liquid
// through the boundary particles' velocities. Built only when a scene has
// bodies: a scene without them has no stage and no memory for them.
#include "core/kernels.h"
#include "sph/particles.h"
#include "sph/setup.h"
#include "sph/state_archive.h"
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace fc {

template <int D> class Simulation;
struct FrameStats;

template <int D>
class RigidBodies {
 public:
  using VecD = Eigen::Matrix<double, D, 1>;
  using Rot = Eigen::Matrix<double, D, D>;
  static constexpr int A = D == 2 ? 1 : 3;  // angular components
  using Ang = Eigen::Matrix<double, A, 1>;

  struct State {
    Body<D> spec;
    size_t first = 0, count = 0;    // its boundary particles
    std::vector<Vec<D>> local;      // their positions in the body frame
    VecD centre = VecD::Zero();     // m
    VecD velocity = VecD::Zero();   // m/s
    Rot rotation = Rot::Identity();
    Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();  // 3D
    double angle = 0;               // rad, 2D
    Ang angularVelocity = Ang::Zero();  // rad/s
    double mass = 0;                // kg (2D: per metre of depth)
    Eigen::Matrix<double, A, A> inertia = Eigen::Matrix<double, A, A>::Identity();  // body frame
    // Per substep, from the liquid: force and torque (about the centre).
    VecD force = VecD::Zero();
    Ang torque = Ang::Zero();
    // Contact impulses the liquid's solid contact gave the body this substep.
    VecD contactImpulse = VecD::Zero();
    Ang contactAngularImpulse = Ang::Zero();
    size_t wallContacts = 0;        // substeps with a wall contact (this frame)

    // Velocity of the body's material point at world position x.
    VecD pointVelocity(const VecD& x) const;
    Real signedDistance(const Vec<D>& x) const;  // world, negative inside
  };

  // Samples every body (its boundary particles are appended to `boundary`,
  // volumes from the body's own samples, Akinci et al. 2012 [AIA*12] eq. (4)).
  RigidBodies(const std::vector<Body<D>>& bodies, Real radius, int layers, const CubicSpline<D>& kernel,
              Real latticeVolume, BoundaryParticles<D>& boundary, const Vec<D>& gravity);

  // Poses at scene time t (kinematic ones from their motion), written to the
  // boundary particles' positions and velocities.
  void place(double time, BoundaryParticles<D>& boundary);
  // After the pressure solve of a substep: the liquid's force on every
  // dynamic body, its integration over dt (gravity included) and contact
  // with the tank walls.
  void integrate(const Simulation<D>& sim, Real dt, const AABB<D>& domain, Real radius);
  // Keeps a liquid particle at least `distance` from every body (centre
  // pushed out, velocity into the body removed relative to the body);
  // returns whether it touched one and whether it had crossed its surface.
  // Particle `particle` must be handled by the thread that handles its
  // whole block of kBlock particles (between beginContacts and endContacts,
  // which adds the impulses to the bodies block by block, in order: the
  // same sums at any thread count).
  void contact(Vec<D>& x, Vec<D>& v, Real mass, Real distance, bool& touched, bool& crossed, size_t particle);
  static constexpr long kBlock = 1024;
  void beginContacts(size_t particles);
  void endContacts();
  bool inside(const Vec<D>& x) const;
  // The bodies' state into the frame's stats (wall contacts counted afresh after).
  void reportFrame(FrameStats& fs);
  // Largest speed of a body's material point (for the time step).
  double maxPointSpeed() const;

  // A rebuilt simulation (a settings edit) continues: kinematic motion at
  // `timeOffset` + its own clock, dynamic bodies in `old`'s state (by name).
  void continueFrom(const RigidBodies& old, double timeOffset);
  // Every body's state is finite.
  bool finite() const;
  // Checkpoints: every body's pose, motion and the substep's forces.
  void archiveState(StateArchive& a);

  const std::vector<State>& states() const { return bodies_; }
  bool anyDynamic() const { return dynamic_; }
  // Index of the body a boundary particle samples, or -1 (walls, obstacles).
  int owner(size_t b) const { return b < firstBody_ ? -1 : owner_[b - firstBody_]; }

 private:
  void poseAt(State& s, double time) const;
  long clearBlockSums(size_t particles);  // zeroed, grown when needed; returns the block count
  std::vector<double> blockSums_;         // per block of particles, per body: D force + A torque terms
  std::vector<double> blockTotal_;
  long contactBlocks_ = 0;
  std::vector<State> bodies_;
  std::vector<int> owner_;
  size_t firstBody_ = 0;
  bool dynamic_ = false;
  double timeOffset_ = 0;  // s, scene time at this simulation's t = 0
  VecD gravity_ = VecD::Zero();
  friend class Simulation<D>;
};

}  // namespace fc
