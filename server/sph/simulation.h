#pragma once
// One liquid simulation: particles, boundaries, neighbour search, the
// pressure solver and the effects the scene names, advanced frame by frame.
#include "core/kernels.h"
#include "core/neighborhood_search.h"
#include "sph/particles.h"
#include "sph/pipeline.h"
#include "sph/bodies/rigid_bodies.h"
#include "sph/setup.h"
#include <array>
#include <atomic>
#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace fc {

// What a template instance did in one frame (filled by control/).
struct InstanceFrameStats {
  std::string name;
  bool active = false;
  int templateFrame = -1;        // template frame played (-1: inactive)
  double fidelity = -1;          // occupancy IoU with the template frame at the frame's start (-1: not measured)
  size_t controlled = 0;         // liquid particles it applied forces to
  size_t controlParticles = 0;   // its template frame's particles
  size_t repulsionParticles = 0; // its repulsion layer's particles (0 when repulsion is off)
};

// A body's state at the end of a frame (sph/bodies/rigid_bodies.h).
struct BodyFrameStats {
  std::string name;
  std::array<double, 3> position{};     // m, centre
  std::array<double, 3> velocity{};     // m/s
  std::array<double, 3> rotationDeg{};  // 2D: [0, 0, angle]; 3D: Euler XYZ
  std::array<double, 3> force{};        // N (2D: N/m), the liquid's pressure force in the last substep
  size_t wallContacts = 0;              // substeps of the frame it touched a tank wall
};

struct FrameStats {
  int frame = 0;                 // index of the frame just completed (1-based)
  double time = 0;               // simulated time at its end, s
  double wallMs = 0;
  int substeps = 0;
  int divergenceIterations = 0;  // summed over substeps
  int densityIterations = 0;     // summed over substeps
  double avgDensityErrorPct = 0; // worst substep's average error at solver exit
  double maxDensityErrorPct = 0; // worst particle error at solver exit
  bool converged = true;         // every solve reached its tolerance
  int unconvergedSubsteps = 0;   // substeps with a solve (divergence, density, implicit viscosity) stopped at its iteration limit
  double stepScale = 1;          // smallest time-step scale a substep of the frame ran at (1: the full step; see Simulation::cflTimeStep)
  int viscosityIterations = 0;   // implicit viscosity (ImplicitVelocities stages) solver iterations, summed over substeps
  bool viscosityConverged = true; // every implicit viscosity solve reached its tolerance (also in `converged`)
  size_t particles = 0;          // liquid particles (all kinds)
  size_t boundaryParticles = 0;
  size_t escapedParticles = 0;   // particles outside the tank or inside a solid at frame end (0 unless broken)
  size_t wallContacts = 0;       // contact corrections (centres kept contact_distance from solids)
  size_t crossedSurface = 0;     // of those, centres that had crossed the solid surface within a substep
  // Momentum the contacts removed against each tank wall over the frame
  // (N·s; N·s/m in 2D), index 2·axis for the min wall, 2·axis + 1 for the
  // max wall: with the boundary particles' force, what the walls carry.
  std::array<double, 6> contactImpulse{};
  std::array<double, 3> boundaryImpulse{};  // what the boundary particles gave the liquid, per axis
  double maxSpeed = 0;           // m/s, end of frame
  double kineticEnergy = 0;      // J (J/m in 2D), end of frame
  double minDt = 0, maxDt = 0;   // s
  double neighborMs = 0;         // wallMs spent in: neighbour search (incl. reordering),
  double densityMs = 0;          //   densities, kernel gradients and solver factors,
  double divergenceMs = 0;       //   the divergence solve,
  double nonPressureMs = 0;      //   gravity and effects,
  double pressureMs = 0;         //   the density (pressure) solve
  double avgNeighbors = 0;
  bool finite = true;            // every position and velocity finite, and the frame completed
  // Why the frame is not valid ("" when finite): a non-finite value, or the
  // watchdog (Simulation::FrameLimits, settings.max_substeps_per_frame)
  // stopped it part-way at `time`. Such a frame is never published.
  // failureText() puts frame and time in front.
  std::string failure;
  bool cancelled = false;        // stopped by FrameLimits::cancel (not a simulation failure)
  // Control (zero without instances; counts as of the frame's end):
  size_t temporaryParticles = 0; // liquid particles of kind Temporary (included in `particles`)
  size_t controlParticles = 0;   // Σ over active instances
  size_t repulsionParticles = 0;
  size_t controlledParticles = 0;
  size_t seededParticles = 0;    // temporary particles created this frame
  size_t removedParticles = 0;   // temporary particles removed this frame
  size_t fadedParticles = 0;     // of those, past their grace period (control's temporary_fade_share bounds them)
  bool emitting = false;         // the scene has emitters (the two counts below are reported)
  size_t emittedParticles = 0;   // liquid particles the emitters added at this frame's start
  size_t emissionBlocked = 0;    // of an emitter's layer, points left out (liquid already there, or max_particles)
  double controlMs = 0;          // of wallMs, spent in control (forces, temporary particles, fidelity)
  std::vector<InstanceFrameStats> instances;
  std::vector<BodyFrameStats> bodies;  // empty without bodies
};

// "frame N (t = T s): <failure>".
std::string failureText(const FrameStats& stats);

// A particle to insert (temporary particles).
template <int D>
struct NewParticle {
  Vec<D> x, v;
  Real mass;
  uint8_t phase;
  ParticleKind kind;
};

template <int D>
class Simulation {
 public:
  // Throws std::invalid_argument naming what is wrong with the setup.
  explicit Simulation(const SimulationSetup<D>& setup);
  ~Simulation();

  // One frame. A frame whose particles have blown up (non-finite values,
  // too many substeps, a collapse the neighbour search cannot list) stops
  // with `failure` set and `finite` false, as one past the watchdog does.
  FrameStats advanceFrame();

  // The watchdog of advanceFrame: checked before every substep. A frame
  // past its deadline, or cancelled, stops there with `failure` set and
  // `finite` false; the state is then mid-frame (rebuild before going on).
  struct FrameLimits {
    std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
    const std::atomic<bool>* cancel = nullptr;
  };
  void setFrameLimits(const FrameLimits& limits) { frameLimits_ = limits; }

  // Checkpoints (sph/state_archive.h): saves or restores everything the next
  // frame reads: particles, clock, time-step control, bodies and every
  // stage's own state (by stage name). Between frames only. A restore
  // continues bit-identically to the run that saved it, at any thread
  // count, provided the setup is the same; a stage absent from the archive
  // (added after it was saved) restarts as new. Throws StateArchiveError
  // on a mismatch (then rebuild the simulation).
  void archiveState(StateArchive& a);

  // A stage built outside sph/ (control), appended to the effects.
  void addEffect(std::unique_ptr<Effect<D>> effect, const std::string& name);
  // Neighbours and densities (with pair gradients) for the current positions,
  // outside a substep; the next substep reuses them if nothing moved.
  void refreshNeighbors();
  // The wall ms of this frame's refresh that its first substep reused: the
  // simulation's own neighbour search and densities, done before the substep
  // (counted in the frame's neighbour and density times, not the caller's).
  double reusedRefreshMs() const { return reusedRefreshMs_; }
  // Between frames only (FrameBoundary stages): every per-particle array of
  // the simulation, its solver and its effects follows. Removal keeps the
  // remaining particles in order; `indices` sorted ascending, unique.
  void appendParticles(const std::vector<NewParticle<D>>& add);
  void removeParticles(const std::vector<uint32_t>& indices);

  const SimulationSetup<D>& setup() const { return setup_; }
  Real particleRadius() const { return radius_; }
  Real supportRadius() const { return kernel.radius(); }
  double time() const { return time_; }
  int frame() const { return frame_; }
  double frameDuration() const { return 1.0 / setup_.settings.frameRate; }
  const std::vector<std::string>& pipelineStages() const { return stageNames_; }
  // Moving bodies (null when the scene has none).
  const RigidBodies<D>* bodies() const { return bodies_.get(); }
  // A simulation rebuilt mid-scene (a settings edit) continues the bodies of
  // `old` at scene time `timeOffset` + its own clock.
  void continueBodiesFrom(const Simulation& old, double timeOffset);
  size_t totalSubsteps() const { return totalSubsteps_; }
  // The factor the current substep's time step is shrunk by after solves
  // that stopped at their iteration limit (1: the full step; cflTimeStep).
  Real stepScale() const { return stepScale_; }
  // Passes that moved overlapping or solid-penetrating particles apart when
  // the simulation was built (relaxInitialState; 0 for a scene-file state).
  int initialRelaxationPasses() const { return relaxationPasses_; }
  Real restDensity(size_t i) const { return restDensity_[fluid.phase[i]]; }
  // The density formulation, chosen once at setup (settings
  // "density_formulation"): false, the mass sum ρ_i = Σ_j m_j W_ij; true,
  // the number density of Solenthaler & Pajarola 2008 [SP08], ρ_i = m_i Σ_j W_ij,
  // for phases of different rest densities (see computeDensities). The
  // pressure solvers read it once per sweep, never per particle.
  bool numberDensity() const { return numberDensity_; }
  // The mass of a liquid particle of `phase` (the fluid blocks' lattice
  // particles; temporary particles copy theirs): rest density times the
  // lattice volume.
  Real particleMass(int phase) const { return restDensity_.at(size_t(phase)) * latticeVolume_; }
  // The scene's boundary model (sph/boundary/, pipeline.h): w, the weight of
  // p_i/ρ_i² in the boundary term of the pressure force, read by the
  // pressure solvers and the bodies' reactions.
  Real boundaryPressureWeight() const { return boundaryWeight_; }
  // The boundary model's set-up time (a volume map's integration) and memory.
  double boundarySetupMs() const { return boundarySetupMs_; }
  size_t boundaryModelBytes() const { return boundaryModel_->memoryBytes(); }

  // State shared with solvers and effects.
  FluidParticles<D> fluid;
  BoundaryParticles<D> boundary;
  CubicSpline<D> kernel;
  NeighborhoodSearch<D> search;
  // Per substep, one entry per fluid neighbour pair, in the CSR order of
  // search.dynamicNeighbors(): m_j F_ij, where m_j ∇W(x_i - x_j) = m_j F_ij
  // (x_i - x_j) (the kernel's gradient points along the pair). One scalar
  // instead of the gradient's D components: a third of the pair memory;
  // the sweeps gather x_j beside v_j (as fast at 1M particles, 8-10 %
  // slower at 59k: docs/benchmarks/paper-scale.md). Positions do not change between the
  // densities and the end of the substep's solves. Masses are folded in
  // because every solver loop multiplies by them. (Under the number density
  // as well: effects read m_j ∇W_ij / ρ_j, which is then the volume form
  // ∇W_ij / δ_j.)
  std::vector<Real> massGradScale;
  const uint32_t* pairOffsets() const { return search.dynamicNeighbors().offsets.data(); }
  // Inside a parallel region: the calling thread's particles [first, last),
  // one of the team's blocks of about equal work (neighbour pairs plus a
  // share per particle), fixed from one neighbour update to the next. Every
  // per-particle loop of a substep uses them, so that the pair sweeps end
  // together (equal blocks of particles differ by up to 8 % in pairs once a
  // dam break flows) and each thread keeps meeting its own particles in its
  // own cache.
  std::pair<long, long> threadParticles() const;
  // threadParticles' weight of a particle's own terms (boundary sums,
  // stores, reductions), in pairs: an estimate, not tuned (the pairs
  // dominate).
  static constexpr long kParticleWorkInPairs = 6;
  const uint32_t* pairNeighbors() const { return search.dynamicNeighbors().indices.data(); }
  // Under the number density only (empty otherwise): F_ij per pair, same
  // order, for the pressure solvers' volume-form pair terms ∇W_ij = F_ij x_ij.
  std::vector<Real> gradScale;
  // m_j ∇W_ij of particle i's pair k.
  Vec<D> massGradWAt(long i, size_t k) const {
    return massGradScale[k] * (fluid.x[size_t(i)] - fluid.x[pairNeighbors()[k]]);
  }
  // ∇W_ij of particle i's pair k (number density only).
  Vec<D> gradWAt(long i, size_t k) const {
    return gradScale[k] * (fluid.x[size_t(i)] - fluid.x[pairNeighbors()[k]]);
  }
  // Per particle, summed over its boundary neighbours b (boundary velocities
  // are constant during a substep, so no solver iteration loops over them):
  std::vector<Vec<D>> boundaryGradW;  // Σ_b V_b ∇W_ib
  std::vector<Real> boundaryFlux;     // Σ_b V_b v_b·∇W_ib
  std::vector<uint16_t> boundaryNeighbors;  // how many b
  // Only where the boundary model extrapolates the wall pressure (empty
  // otherwise): Σ_b V_b (g·(x_b - x_i)) ∇W_ib, the hydrostatic part of the
  // samples' pressure force per unit mass with its sign reversed.
  std::vector<Vec<D>> boundaryExtrapolation;
  // Only where the mirror enters the density constraint (empty otherwise):
  // what the pressure solvers add to ρ_i, ρ0_i c Σ_b V_b W_ib s((r - d_ib)/r)
  // over the static samples, d_ib the particle's distance from sample b's
  // own stretch of solid surface, s a ramp (computeDensities). It is zero at
  // the rest distance and beyond, and grows as the particle comes nearer; its gradient is in boundaryGradW, so the
  // push and the density it corrects follow one function of the positions.
  // c makes that push, at the rest distance from a flat wall, the wall's
  // push once more, as the mirrored liquid of [AHA12] adds.
  std::vector<Real> boundaryExcess;
  // Σ_b V_b ∇W(x - x_b) over the solids, as boundaryGradW holds it for a
  // particle at x (the same sums), without computing every particle's.
  Vec<D> boundaryGradientAt(const Vec<D>& x) const;
  // The density the pressure solvers correct: ρ_i, plus boundaryExcess where there is one.
  Real constrainedDensity(size_t i) const { return fluid.density[i] + (boundaryExcess.empty() ? Real(0) : boundaryExcess[i]); }
  std::vector<Real> restDensity_;   // per phase

 private:
  FrameStats advanceFrameSteps();
  // fs as a frame that stops here: not finite, `why` its failure, timed from t0.
  FrameStats stoppedFrame(FrameStats fs, std::string why, std::chrono::steady_clock::time_point t0) const;
  void buildBoundary();
  void buildFluid();
  void computeDensities();
  void splitWork();
  template <bool NumberDensity>
  void computeDensitiesWith();
  // What a particle at x gets from the solids: computeDensities' boundary
  // sums, one particle at a time (inlined into the density pass).
  struct StaticSums {
    Real volume = 0, flux = 0, excess = 0;
    Vec<D> grad = Vec<D>::Zero(), extrapolated = Vec<D>::Zero();
    unsigned count = 0;
  };
  StaticSums staticSumsAt(const Vec<D>& xi) const;
  // The substep's time step; nullopt when a particle's speed is not finite.
  std::optional<Real> cflTimeStep() const;
  void updateStepScale(bool converged);
  void relaxInitialState();
  void averagePressure(Real dt);
  void reorderParticles();
  void enforceSolidContact(FrameStats& fs);
  void addStages(Effect<D>* eff);

  SimulationSetup<D> setup_;
  FrameLimits frameLimits_;
  Real radius_;
  Real latticeVolume_ = 0;  // volume per particle of the initial lattice
  Vec<D> gravity_;
  std::unique_ptr<PressureSolver<D>> pressure_;
  std::unique_ptr<BoundaryModel<D>> boundaryModel_;
  Real boundaryWeight_ = 1;
  bool extrapolateBoundary_ = false;
  bool mirrorInConstraint_ = false;
  Real mirrorScale_ = 0;     // c
  Real mirrorRamp_ = 1;      // τ: the depth, in r, over which the mirror's push sets in
  std::vector<Vec<D>> surfaceNormal_;  // per static sample: its solid's outward normal, the liquid's side
  std::vector<Real> surfaceDepth_;     // per static sample: its depth below that surface
  bool mapStaticSolids_ = false;  // the boundary model stands in for the static samples
  size_t staticSamples_ = 0;      // boundary samples of static solids (the bodies' follow)
  double boundarySetupMs_ = 0;
  std::vector<std::unique_ptr<Effect<D>>> effects_;
  std::unique_ptr<RigidBodies<D>> bodies_;
  std::vector<Effect<D>*> accelerationStages_, implicitStages_, velocityStages_, frameStages_;
  bool neighborsFresh_ = false;
  double refreshNeighborMs_ = 0, refreshDensityMs_ = 0, reusedRefreshMs_ = 0;  // refreshNeighbors' times
  std::vector<long> workSplit_;  // threadParticles' blocks: thread t has [t], [t + 1]
  bool numberDensity_ = false;
  Real contrastStep_ = 1;  // number density: time step scale, see cflTimeStep
  Real stepScale_ = 1;     // shrinks after unconverged solves, see cflTimeStep
  int relaxationPasses_ = 0;
  uint32_t nextId_ = 0;
  std::vector<std::string> stageNames_;
  double time_ = 0;
  int frame_ = 0;
  Real lastDt_ = 0;
  size_t totalSubsteps_ = 0;
  size_t stepsSinceReorder_ = 0;
  std::vector<uint32_t> perm_;
  typename FluidParticles<D>::Scratch reorderScratch_;
};

}  // namespace fc
