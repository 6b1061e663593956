#pragma once
// Pluggable parts of the step: pressure solvers, non-pressure effects and
// boundary models.
// Each registers by name in one table; the scene's lists pick which exist.
#include "core/types.h"
#include "sph/parameters.h"
#include "sph/state_archive.h"
#include <array>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

template <int D> class Simulation;
struct FrameStats;

struct SolverReport {
  int iterations = 0;
  double avgErrorPct = 0;   // average relative error at exit, percent
  double maxErrorPct = 0;   // largest particle error at exit, percent
  bool converged = true;
  // Momentum the boundary gave the liquid during this solve (N·s; N·s/m in
  // 2D), per axis: what the walls carry, measured where it is applied.
  std::array<double, 3> boundaryImpulse{};
};

template <int D>
class PressureSolver {
 public:
  virtual ~PressureSolver() = default;
  // Called once after the particles exist and before the first step.
  virtual void init(Simulation<D>&) {}
  // After densities and kernel gradients of a substep are known.
  virtual void prepare(Simulation<D>&) {}
  // Before non-pressure forces: DFSPH's divergence-free solve.
  virtual SolverReport correctDivergence(Simulation<D>&, Real /*dt*/) { return {}; }
  // After v += dt·a: make the predicted density match the rest density.
  virtual SolverReport correctDensity(Simulation<D>&, Real dt) = 0;
  // Largest time step this solver allows besides the velocity CFL (s).
  virtual Real maxTimeStep(const Simulation<D>&) const { return Real(1e30); }
  virtual void reorder(const std::vector<uint32_t>&) {}
  virtual void resize(size_t) {}
  // Checkpoints (sph/state_archive.h): the state this part carries from one
  // frame to the next (warm starts, counters, per-particle memory), saved
  // and restored in the particles' current order. Called between frames;
  // on load after resize() to the restored particle count. Stateless parts
  // keep the default.
  virtual void archiveState(StateArchive&) {}
};

// Stages an effect takes part in; the pipeline only calls what is declared.
// Order within a substep: AddAccelerations (a, before Δt is known), then
// v* = v + Δt·a, then ImplicitVelocities (v* and Δt: implicit solves that
// must act before the pressure solve, e.g. implicit viscosity), then the
// density solve, then CorrectVelocities (after it).
enum EffectStage : unsigned { AddAccelerations = 1, CorrectVelocities = 2, FrameBoundary = 4, ImplicitVelocities = 8 };

template <int D>
class Effect {
 public:
  virtual ~Effect() = default;
  virtual unsigned stages() const = 0;
  virtual void init(Simulation<D>&) {}
  virtual void addAccelerations(Simulation<D>&) {}
  virtual void correctVelocities(Simulation<D>&, Real /*dt*/) {}
  // ImplicitVelocities: replaces the predicted velocities v* = v + Δt·a of
  // this substep (every non-pressure acceleration, control forces included)
  // with the solution of an implicit system in Δt, before the pressure solve
  // sees them. Reports its solve (iterations, convergence, boundary impulse).
  // It exists because neither of the other stages can express this:
  // AddAccelerations runs before Δt is chosen (the CFL step depends on the
  // accelerations), and CorrectVelocities runs after the pressure solve,
  // whose divergence-free result a viscosity solve would then undo.
  virtual SolverReport solveVelocities(Simulation<D>&, Real /*dt*/) { return {}; }
  // FrameBoundary: before the first substep of a frame (the only place where
  // particles may be added or removed) and after its last one.
  virtual void beginFrame(Simulation<D>&, FrameStats&) {}
  virtual void endFrame(Simulation<D>&, FrameStats&) {}
  // Largest time step this effect stays stable with (s).
  virtual Real maxTimeStep(const Simulation<D>&) const { return Real(1e30); }
  virtual void reorder(const std::vector<uint32_t>&) {}
  virtual void resize(size_t) {}
  // Checkpoints (sph/state_archive.h): the state this part carries from one
  // frame to the next (warm starts, counters, per-particle memory), saved
  // and restored in the particles' current order. Called between frames;
  // on load after resize() to the restored particle count. Stateless parts
  // keep the default.
  virtual void archiveState(StateArchive&) {}
};

// How the liquid's pressure acts on it at solids (sph/boundary/). Every
// model uses the same boundary samples and per-particle sums
// (Simulation::boundaryGradW and the rest); the model says which pressure
// p_b a sample carries in the pair term of the pressure force,
//   a_i = -Σ_b Ψ_b (w p_i/ρ_i² + Δp_b/ρ0_i²) ∇W_ib,
// w = 1 for Akinci et al.'s term alone, w = 2 where the sample mirrors p_i
// in the symmetric pair term, and Δp_b the pressure extrapolated into the
// solid beyond p_i (Simulation::boundaryExtrapolation). A model that maps
// the static solids (mapsStaticSolids) replaces their samples in those
// per-particle sums by its own terms (staticTerms); moving bodies keep their
// samples.
template <int D>
struct StaticBoundaryTerms {
  Real volume = 0;                       // Σ_b V_b W_ib
  Vec<D> grad = Vec<D>::Zero();          // Σ_b V_b ∇W_ib
  Vec<D> extrapolation = Vec<D>::Zero(); // Σ_b V_b (g·(x_b - x_i)) ∇W_ib
  unsigned samples = 0;                  // how many lattice samples that stands for
};

template <int D>
class BoundaryModel {
 public:
  virtual ~BoundaryModel() = default;
  virtual Real pressureWeight() const = 0;
  // Whether samples carry the hydrostatic extrapolation Δp_b = ρ0_i (g - a_b)·(x_b - x_i).
  virtual bool extrapolatesPressure() const = 0;
  virtual bool mapsStaticSolids() const { return false; }
  // With w = 2: whether the mirror enters the density the pressure solvers
  // correct, as a term of its own that grows nearer than the rest distance
  // (Simulation::boundaryExcess), so that the push and the density it
  // corrects follow one gradient; and the depth, in particle radii, over
  // which its push sets in.
  virtual bool mirrorsInConstraint() const { return false; }
  virtual Real mirrorRamp() const { return 1; }
  // Once, after the boundary is built; `latticeVolume` is a fluid particle's rest volume.
  virtual void setUp(const Simulation<D>&, Real /*latticeVolume*/) {}
  // The static solids' terms for a particle at x under gravity g; false: none (out of their reach).
  virtual bool staticTerms(const Vec<D>& /*x*/, const Vec<D>& /*g*/, StaticBoundaryTerms<D>&) const { return false; }
  virtual size_t memoryBytes() const { return 0; }
};

// A name -> (parameter specs, factory) table.
template <class Product>
class Registry {
 public:
  struct Entry {
    std::string help;
    ParamSpecs params;
    std::function<std::unique_ptr<Product>(const ParamValues&)> make;
  };
  static Registry& instance() {
    static Registry r;
    return r;
  }
  bool add(const std::string& name, Entry e) {
    entries_[name] = std::move(e);
    return true;
  }
  const Entry* find(const std::string& name) const {
    auto it = entries_.find(name);
    return it == entries_.end() ? nullptr : &it->second;
  }
  std::vector<std::string> names() const {
    std::vector<std::string> n;
    for (auto& [k, v] : entries_) n.push_back(k);
    return n;
  }
  std::unique_ptr<Product> make(const std::string& name, const ParamValues& p) const {
    const Entry* e = find(name);
    if (!e) throw std::invalid_argument("unknown '" + name + "'");
    return e->make(p);
  }

 private:
  std::map<std::string, Entry> entries_;
};

template <int D> using PressureSolverRegistry = Registry<PressureSolver<D>>;
template <int D> using EffectRegistry = Registry<Effect<D>>;
template <int D> using BoundaryModelRegistry = Registry<BoundaryModel<D>>;

// Registration happens in one place (sph/registry.cpp) so that static
// libraries cannot drop it.
void registerBuiltinSolversAndEffects();

}  // namespace fc
