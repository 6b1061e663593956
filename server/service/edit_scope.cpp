// Which recorded frames an edit changes: see edit_scope.h.
#include "service/edit_scope.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <vector>

namespace fc::service {

namespace {

template <int D>
bool sameKey(const TransformKey<D>& a, const TransformKey<D>& b) {
  return a.time == b.time && a.translation == b.translation && a.rotationDeg == b.rotationDeg && a.scale == b.scale &&
         a.reflect == b.reflect;
}

bool sameTimeMap(const TimeMap& a, const TimeMap& b) {
  return a.start == b.start && a.cropBegin == b.cropBegin && a.cropEnd == b.cropEnd && a.speed == b.speed &&
         a.reverse == b.reverse;
}

// Both tracks give exactly the same pose (and, with `velocity`, the same
// carried velocity, taken in the segment starting at `time`).
template <int D>
bool sameAt(const TransformTrack<D>& a, const TransformTrack<D>& b, double time, bool velocity = true) {
  Eigen::Matrix<double, D, D> la, lb, ga, gb;
  Eigen::Matrix<double, D, 1> ta, tb, oa, ob;
  a.evaluate(time, la, ta);
  b.evaluate(time, lb, tb);
  if (!(la == lb && ta == tb)) return false;
  if (!velocity) return true;
  a.velocityMap(time, ga, oa);
  b.velocityMap(time, gb, ob);
  return ga == gb && oa == ob;
}

// The time from which the tracks may differ. Between two consecutive key
// times of either track both are one interpolation (linear, slerp; a
// reflection switching only at a key), so agreeing at an interval's ends
// and middle is agreeing on it; before the first key both hold it.
template <int D>
double tracksAgreeUntil(const TransformTrack<D>& a, const TransformTrack<D>& b) {
  if (a.keys.size() == b.keys.size()) {
    size_t k = 0;
    while (k < a.keys.size() && sameKey(a.keys[k], b.keys[k])) ++k;
    if (k == a.keys.size()) return kNeverAffected;
  }
  std::vector<double> times;
  for (const auto* t : {&a, &b})
    for (const auto& key : t->keys) times.push_back(key.time);
  if (times.empty()) return kAffectedFromStart;
  std::sort(times.begin(), times.end());
  times.erase(std::unique(times.begin(), times.end()), times.end());
  if (!sameAt(a, b, times.front() - 1)) return kAffectedFromStart;
  for (size_t i = 0; i < times.size(); ++i) {
    const double lo = times[i], hi = i + 1 < times.size() ? times[i + 1] : lo + 1;
    if (!sameAt(a, b, lo) || !sameAt(a, b, 0.5 * (lo + hi)) || !sameAt(a, b, hi, false)) return lo;
  }
  return kNeverAffected;
}

}  // namespace

template <int D>
double firstAffectedTime(const InstanceSpec<D>* before, const InstanceSpec<D>* after) {
  if (!before && !after) return kNeverAffected;
  if (!before) return after->time.start;
  if (!after) return before->time.start;
  const double start = std::min(before->time.start, after->time.start);
  const bool restSame = before->templateName == after->templateName && before->phase == after->phase &&
                        before->params == after->params && sameTimeMap(before->time, after->time);
  if (!restSame) return start;
  // Only the track: from where the tracks part, but never before the instance acts.
  const double track = tracksAgreeUntil(before->transform, after->transform);
  return track == kNeverAffected ? kNeverAffected : std::max(track, start);
}

int firstAffectedFrame(double time, double frameDuration) {
  if (time == kNeverAffected || std::isnan(time)) return INT_MAX;
  if (time == kAffectedFromStart || time < frameDuration) return 1;
  const double guess = std::floor(time / frameDuration) + 1;
  if (guess >= double(INT_MAX) - 2) return INT_MAX;
  int n = int(guess);
  // The simulation's own frame ends (Simulation::advanceFrame), not the quotient's rounding.
  while (n > 1 && double(n - 1) * frameDuration > time) --n;
  while (double(n) * frameDuration <= time) ++n;
  return n;
}

template double firstAffectedTime<2>(const InstanceSpec<2>*, const InstanceSpec<2>*);
template double firstAffectedTime<3>(const InstanceSpec<3>*, const InstanceSpec<3>*);

}  // namespace fc::service
