#pragma once
// Regular particle sampling of volumes (fluid blocks), shared by the
// simulation and by scene validation (which must count particles before
// creating them).
#include "core/aabb.h"
#include <algorithm>
#include <cmath>

namespace fc {

// Points of a lattice with the given spacing filling box, inset by half a
// spacing from each face (so a block touching a wall starts one particle
// radius away from it).
template <int D>
VecI<D> latticeDims(const AABB<D>& box, Real spacing) {
  VecI<D> n;
  for (int d = 0; d < D; ++d)
    n[d] = std::max(0, int(std::floor(box.size()[d] / spacing + Real(1e-4))));
  return n;
}

template <int D>
size_t latticeCount(const AABB<D>& box, Real spacing) {
  if (box.empty()) return 0;
  const VecI<D> n = latticeDims(box, spacing);
  size_t c = 1;
  for (int d = 0; d < D; ++d) c *= size_t(n[d]);
  return c;
}

template <int D, class F>
void forEachLatticePoint(const AABB<D>& box, Real spacing, F&& f) {
  if (box.empty()) return;
  const VecI<D> n = latticeDims(box, spacing);
  // Centre the lattice in the box.
  Vec<D> origin;
  for (int d = 0; d < D; ++d) origin[d] = box.min[d] + Real(0.5) * (box.size()[d] - (n[d] - 1) * spacing);
  VecI<D> i = VecI<D>::Zero();
  if ((n.array() <= 0).any()) return;
  while (true) {
    f(Vec<D>(origin + spacing * i.template cast<Real>()));
    int d = 0;
    while (d < D && ++i[d] == n[d]) i[d++] = 0;
    if (d == D) break;
  }
}

}  // namespace fc
