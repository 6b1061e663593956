#pragma once
// Template instances steering the liquid (paper §3.3–§3.5): a pipeline stage
// that, once per frame (or every substep, `forces_every_substep`), evaluates
// every active instance in its template's space and adds the control
// accelerations, seeds and removes temporary particles between frames, and
// measures how closely the liquid reproduces each template (fidelity).
//
// Normalisation (why the weights do not depend on the liquid's resolution).
// Every sum over control or repulsion particles is an SPH interpolation in
// template space: each term carries the template particle's volume
// V_j = m_j / ρ0_template, and the kernel is Poly6 with the TEMPLATE's
// support radius h_T. Σ_j V_j W(x − x_j, h_T) is ≈ 1 inside the template
// whatever its resolution, and the liquid enters only through α (eq. 3),
// itself the interpolation Σ_i (m_i/ρ_i) W with the liquid volumes mapped to
// template space. Halving the liquid's particle radius therefore leaves every
// acceleration unchanged. The weights scale two reference constants:
//   a_attraction = w_a · A · Σ_j V_j α_j W(d_j, h_T) (x_j − x)/d_j           (eq. 2)
//   a_velocity   = w_v · K · Σ_j V_j (1 − α_j) (v_j − v) W(d_j, h_T)          (eq. 4)
//   a_repulsion  = w_r · A · Σ_k V_k n_k W(d_k, h_T)                          (eq. 5)
// with A = kAccelerationScale (m/s²) and K = kRateScale (1/s), evaluated in
// template space and mapped to the world by the instance's linear part, then
// faded by t^γ across the falloff band. n_k points from the repulsion particle
// back towards the template's liquid.
#include "control/instance.h"
#include "core/kernels.h"
#include "core/neighborhood_search.h"
#include "sph/pipeline.h"
#include "sph/simulation.h"
#include <array>
#include <vector>

namespace fc {

// A w = 1 attraction or repulsion sum of 1 (full coverage) is this
// acceleration, and a w = 1 velocity sum relaxes a velocity difference at this
// rate. Tuned on the 2D drop reproduction (ControlReproduction test): with the
// paper's default weights the pull at an uncovered template surface (sum
// ≈ 0.3–0.5) is 2–3 g in 2D and under 1 g in 3D, and covered liquid relaxes
// towards the template's velocity at 90 /s (2D) and 30 /s (3D). Stronger
// attraction (1000 m/s²) measured lower fidelity: it clumps the liquid
// against the template surface; stronger velocity relaxation saturates at the
// cap of one relaxation per application.
constexpr Real kAccelerationScale = 300;  // m/s²
constexpr Real kRateScale = 3000;         // 1/s

template <int D>
class Control : public Effect<D> {
 public:
  // Instances must be bound (template loaded, transform track not empty).
  Control(std::vector<BoundInstance<D>> instances, const ControlSettings& settings);

  unsigned stages() const override { return AddAccelerations | FrameBoundary; }
  void beginFrame(Simulation<D>& sim, FrameStats& fs) override;
  void addAccelerations(Simulation<D>& sim) override;
  void endFrame(Simulation<D>& sim, FrameStats& fs) override;
  void reorder(const std::vector<uint32_t>& perm) override;
  void resize(size_t n) override;
  void archiveState(StateArchive& a) override;

  const std::vector<BoundInstance<D>>& instances() const { return instances_; }

  // ---- sessions (service/session.h): edits between frames ----
  // Replaces the instances (bound, as for the constructor) at a frame
  // boundary; every instance's per-frame state restarts. Temporary particles
  // already in the liquid stay and are removed by the usual rules.
  void setInstances(std::vector<BoundInstance<D>> instances);
  // Scene time = sim.time() + offset: a session that rebuilt its simulation
  // mid-run (a settings change) keeps its scene clock.
  void setTimeOffset(double seconds) { timeOffset_ = seconds; }
  // Counts the temporary particles the simulation already holds (a stage
  // added to a running simulation takes over their removal) and forgets
  // every particle's history (a stage as new).
  void init(Simulation<D>& sim) override;

  // ---- exposed for tests and tools ----
  // Selects the instances active at scene time `time` and their template
  // frames and transforms (as beginFrame does).
  void selectActive(double time);
  bool isActive(size_t instance) const { return state_[instance].on; }
  size_t templateFrame(size_t instance) const { return state_[instance].frame; }
  // Evaluates the control accelerations of the active instances for the
  // current particles (neighbours and densities must be fresh) into
  // controlAcceleration(); `applyFor` is the time they will be applied over
  // (caps the velocity relaxation so that it cannot overshoot).
  void computeForces(Simulation<D>& sim, Real applyFor);
  const std::vector<Vec<D>>& controlAcceleration() const { return controlAcc_; }
  // Coverage α_j of the control particles of an active instance (eq. 3).
  const std::vector<Real>& coverage(size_t instance) const { return state_[instance].alpha; }
  // Template space → world of an active instance, as used by the last
  // evaluation (the frame's start, or the substep's with forces_every_substep).
  const Affine<D>& toWorld(size_t instance) const { return state_[instance].toWorld; }
  // Occupancy IoU of an active instance at the last computeForces (-1: none).
  double fidelity(size_t instance) const { return state_[instance].fidelity; }

 private:
  struct State {
    bool on = false;         // active at the current frame
    size_t frame = 0;        // template frame
    Poly6<D> kernel;         // h_T of the template
    Affine<D> toWorld, toTemplate;
    Real volumeScale = 1;    // |det| of toWorld's linear part
    AABB<D> region;          // the template's capture region (the instance box, template space)
    Vec<D> falloff;          // band width per template axis (template units)
    Real decay = 1;          // γ of the fade t^γ
    AABB<D> gatherBox;       // template space: region grown by max(band, h_T)
    AABB<D> worldBox;        // world AABB of gatherBox
    AABB<D> regionWorldBox;  // world AABB of region
    Mat<D> velocityGradient = Mat<D>::Zero();  // world velocity of carried points: G (x_world) + g
    Vec<D> velocityOffset = Vec<D>::Zero();
    Real velocityFactor = 1; // speed, negated when reversed
    std::vector<Real> alpha; // per control particle of the frame
    std::vector<uint32_t> liquid;  // gathered liquid particles
    std::vector<Vec<D>> y;         // their template-space positions
    std::vector<Real> fade;        // t^γ (0 outside the band)
    double fidelity = -1;
  };

  void prepare(size_t i, double time);
  void gather(size_t i, const Simulation<D>& sim);
  void computeCoverage(size_t i, const Simulation<D>& sim);
  void addInstanceForces(size_t i, Simulation<D>& sim, Real applyFor);
  double measureFidelity(size_t i);
  // Position across the falloff band: 1 inside the box, 0 at and beyond the
  // band's outer edge.
  Real bandCoordinate(size_t i, const Vec<D>& y) const;
  bool insideBox(size_t i, const Vec<D>& y) const;
  bool insideAnyInstance(const Vec<D>& xWorld) const;  // falloff box included
  void clearParticleMemory();
  // Algorithms 1 and 2 (temporary_particles.cpp).
  void updateTemporaryParticles(Simulation<D>& sim, FrameStats& fs);

  std::vector<BoundInstance<D>> instances_;
  ControlSettings settings_;
  std::vector<State> state_;          // one per instance
  std::vector<uint8_t> occupancy_;    // fidelity scratch
  std::vector<uint32_t> fidelityCells_;
  std::vector<uint32_t> candidates_;  // gather scratch (kept: no allocation in a step)
  std::vector<Vec<D>> candidateY_;
  std::vector<Real> candidateFade_;   // < 0: not gathered
  std::vector<size_t> keptBefore_;    // per thread: candidates kept by the threads before it
  std::vector<uint32_t> seedSources_; // seeding scratch: liquid near an instance box
  std::vector<uint32_t> temporaryScratch_;  // removal pass scratch
  std::vector<uint8_t> verdictScratch_;
  std::vector<uint32_t> overdueScratch_;
  std::vector<uint8_t> emittedScratch_;     // seeding: a source already seeded this frame
  std::vector<std::vector<std::pair<uint32_t, NewParticle<D>>>> seedCandidates_;  // per thread
  NeighborhoodSearch<D> localGrid_;   // gathered liquid in template space (for α and the forces)
  std::vector<Real> sortedVolume_;    // their volumes m/ρ, in localGrid_'s cell order
  std::vector<Real> sortedMass_;      // seeding: control masses in their grid's order
  std::vector<std::array<std::vector<Real>, D>> pairGradients_;  // seeding: one particle's m_j ∇W_ij, per thread
  std::vector<std::vector<uint32_t>> sourceNeighbors_;           // seeding: one particle's neighbour list, per thread
  // The frame's control and repulsion particles in grids (template space,
  // localGrid_'s cells), and per particle in their cell order what the
  // force sums read: α m/ρ0, (1 − α) m/ρ0, v_j per axis (control);
  // m/ρ0 · n_k per axis (repulsion).
  NeighborhoodSearch<D> controlGrid_, repulsionGrid_;
  std::vector<Real> forceA_, forceC_;
  std::array<std::vector<Real>, D> forceV_, forceR_;
  std::vector<uint32_t> occupiedCells_;         // the cells holding points (controlGrid_'s, then localGrid_'s)
  std::vector<std::vector<Real>> nearPoints_;   // per thread: the fields near one cell
  std::vector<Vec<D>> controlAcc_;    // per liquid particle
  std::vector<uint32_t> controlled_;  // particles with a non-zero controlAcc_
  std::vector<uint8_t> touched_;      // per particle: in controlled_
  std::vector<uint32_t> framesOutside_;  // temporary particles: frames outside every instance
  std::vector<uint32_t> inverse_;     // reorder scratch (kept: no allocation in a step)
  std::vector<Vec<D>> accScratch_;
  std::vector<uint32_t> outsideScratch_;
  std::vector<uint8_t> touchedScratch_;
  bool forcesDue_ = true;
  double controlMs_ = 0;              // this frame
  size_t seeded_ = 0, removed_ = 0;   // this frame
  size_t faded_ = 0;                  // this frame: removed past their grace period
  size_t temporaries_ = 0;            // temporary particles alive
  bool measureFidelity_ = true;       // at the frame's first force evaluation
  double timeOffset_ = 0;             // scene time − sim.time()
};

}  // namespace fc
