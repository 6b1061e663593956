#pragma once
// Which recorded frames an edit changes: the first scene time at which the
// simulation with the edit can differ from the one without it. Sessions
// keep every frame before it and re-simulate from there (checkpoints.h).
#include "control/instance.h"

#include <limits>

namespace fc::service {

// Nothing changes at any time.
inline constexpr double kNeverAffected = std::numeric_limits<double>::infinity();
// Changes from the scene's start (frame 1 on).
inline constexpr double kAffectedFromStart = -std::numeric_limits<double>::infinity();

// An instance replaced by another (either may be null: added, removed).
// An instance acts only from its start (control, temporary particles), so
// a change is felt from the earlier of the two starts, or later still when
// only the transform track changed: after the last key both tracks share
// (the interpolation into the first differing key starts there).
template <int D>
double firstAffectedTime(const InstanceSpec<D>* before, const InstanceSpec<D>* after);

// The first frame whose simulation reads scene time `time` or later: frame n
// covers (t(n−1), t(n)] with t(n) = n · frameDuration as the simulation
// computes it, and evaluates the scene at times below t(n) − 1e-9 (the last
// substep starts before that; an instance counts as started 1e-9 s early),
// so it is the first n with t(n) > time. kAffectedFromStart gives 1;
// kNeverAffected INT_MAX.
int firstAffectedFrame(double time, double frameDuration);

}  // namespace fc::service
