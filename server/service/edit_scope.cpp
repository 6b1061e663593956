// Which recorded frames an edit changes: see edit_scope.h.
#include "service/edit_scope.h"

#include <algorithm>
#include <climits>
#include <cmath>

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

// The last time both tracks certainly agree up to (they may differ after it).
template <int D>
double tracksAgreeUntil(const TransformTrack<D>& a, const TransformTrack<D>& b) {
  const size_t common = std::min(a.keys.size(), b.keys.size());
  size_t k = 0;
  while (k < common && sameKey(a.keys[k], b.keys[k])) ++k;
  if (k == a.keys.size() && k == b.keys.size()) return kNeverAffected;
  // Before the first key the first key holds: a changed first key changes everything.
  return k == 0 ? kAffectedFromStart : a.keys[k - 1].time;
}

}  // namespace

template <int D>
double firstAffectedTime(const InstanceSpec<D>* before, const InstanceSpec<D>* after) {
  if (!before && !after) return kNeverAffected;
  if (!before) return after->time.start;
  if (!after) return before->time.start;
  const double start = std::min(before->time.start, after->time.start);
  const bool restSame = before->templateName == after->templateName && before->phase == after->phase &&
                        before->params.all() == after->params.all() && sameTimeMap(before->time, after->time);
  if (!restSame) return start;
  // Only the track: from where the tracks part, but never before the instance acts.
  const double track = tracksAgreeUntil(before->transform, after->transform);
  return track == kNeverAffected ? kNeverAffected : std::max(track, start);
}

int firstAffectedFrame(double time, double frameRate) {
  if (time == kNeverAffected || std::isnan(time)) return INT_MAX;
  if (time == kAffectedFromStart) return 1;
  const double f = std::floor(time * frameRate - 1e-6) + 1;
  if (f < 1) return 1;
  return f >= double(INT_MAX) ? INT_MAX : int(f);
}

template double firstAffectedTime<2>(const InstanceSpec<2>*, const InstanceSpec<2>*);
template double firstAffectedTime<3>(const InstanceSpec<3>*, const InstanceSpec<3>*);

}  // namespace fc::service
