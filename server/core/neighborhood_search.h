#pragma once
// Uniform-grid neighbour search over a bounded domain.
//
// Cells have the size of the search radius, so a particle's neighbours lie in
// the 3^D cells around its own. Cells are numbered x-fastest, and particles
// are counting-sorted by cell every update, so the three cells of a row along
// x are one contiguous range: a 3D query scans 9 ranges instead of 27.
// Neighbour lists are stored compactly (CSR: one offset per particle, one
// uint32 per pair). Points outside the grid are clamped to its border cells,
// which keeps the result exact (clamping never separates two cells that were
// adjacent) and only costs speed.
#include "core/aabb.h"
#include "core/types.h"
#include <algorithm>
#include <array>
#include <cassert>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

struct NeighborList {
  std::vector<uint32_t> offsets;  // size n+1
  std::vector<uint32_t> indices;  // neighbours of i: indices[offsets[i] .. offsets[i+1]); room past pairs()
  uint32_t count(uint32_t i) const { return offsets[i + 1] - offsets[i]; }
  const uint32_t* begin(uint32_t i) const { return indices.data() + offsets[i]; }
  const uint32_t* end(uint32_t i) const { return indices.data() + offsets[i + 1]; }
  size_t pairs() const { return offsets.empty() ? 0 : offsets.back(); }
  // Each build's pairs per thread block: the next build writes every block
  // straight into `indices`, in a region this large plus a margin, instead
  // of into a private buffer copied over (which held a second copy of the
  // list). `indices` keeps its size between builds (the regions share it):
  // it is allocated again only when the regions outgrow it.
  std::vector<size_t> blockPairs;
};

// The points have piled up so densely that their neighbour lists cannot be
// built (a simulation that has blown up): update() throws it instead of
// spending O(n²) time and memory on them.
class NeighborCollapse : public std::runtime_error {
 public:
  explicit NeighborCollapse(const std::string& how)
      : std::runtime_error("the particles have collapsed onto each other (" + how +
                           "): the simulation has become unstable") {}
};

template <int D>
class NeighborhoodSearch {
 public:
  // The grid covers `domain`; radius is the search radius (cell size).
  void setGrid(const AABB<D>& domain, Real radius);
  Real radius() const { return radius_; }
  size_t cellCount() const { return cellCount_; }

  // A second point set (boundary particles) whose grid is built here and
  // kept until the next call.
  void setStaticPoints(const std::vector<Vec<D>>& points);

  // Rebuilds the dynamic grid from x and the neighbour list of every x[i]
  // among x (self excluded). Throws NeighborCollapse when the points have
  // piled up (the lists are then empty).
  void update(const std::vector<Vec<D>>& x);
  // Rebuilds the dynamic grid from x only: the queries below then see x,
  // while dynamicNeighbors() keeps the last update's lists.
  void updateGrid(const std::vector<Vec<D>>& x);
  // The dynamic points within radius() of p, except `self`, in the order
  // update() lists them for a point at p: one list without building all.
  void dynamicNeighborsOf(const Vec<D>& p, uint32_t self, std::vector<uint32_t>& out) const;
  const NeighborList& dynamicNeighbors() const { return dyn_; }

  // Static neighbours of every x[i], as a list. The solver does not need it
  // (it sums over static neighbours with forEachStaticNear); tools and
  // effects that keep per-pair data do.
  void staticNeighborLists(const std::vector<Vec<D>>& x, NeighborList& out);

  // What the search holds: grids, sorted copies, lists and scratch
  // (capacities, in bytes).
  size_t memoryBytes() const;

  // Permutation that orders x along the Morton curve of their cells:
  // new index k holds old particle perm[k].
  void zOrder(const std::vector<Vec<D>>& x, std::vector<uint32_t>& perm) const;

  // Dynamic points (as of the last update) within `r` <= radius of p.
  template <class F>
  void forEachDynamicNear(const Vec<D>& p, Real r, F&& f) const {
    forEachNear(p, r, dynStart_, dynSorted_, dynSortedIdx_, f);
  }
  template <class F>
  void forEachStaticNear(const Vec<D>& p, Real r, F&& f) const {
    forEachNear(p, r, statStart_, staticPos_, staticIdx_, f);
  }

  // The static points in cell order, for callers that run their own
  // (vectorised) loop over forEachStaticRange's ranges: axis d's
  // coordinates, and each one's index into the array setStaticPoints got.
  const Real* staticSorted(int d) const { return staticPos_[d].data(); }
  const uint32_t* staticOrder() const { return staticIdx_.data(); }
  size_t staticCount() const { return staticIdx_.size(); }
  // Cell c's static points are [start[c], start[c + 1]) of the sorted
  // arrays (cellCount() + 1 entries once setStaticPoints ran).
  const uint32_t* staticCellStart() const { return statStart_.data(); }
  // f(begin, end) for each row of cells around p: every static point within
  // r <= radius() of p is in one of these ranges of the sorted arrays.
  // (Trimming each row to the sphere's chord by binary search over x-sorted
  // cells was measured 2-5x slower: the searches cost more than the
  // candidates they drop.)
  template <class F>
  void forEachStaticRange(const Vec<D>& p, Real r, F&& f) const {
    assert(r <= radius_ * Real(1.000001));
    (void)r;
    forEachRow(p, statStart_, f);
  }

  // Indices of the dynamic points (as of the last update) inside `box`, in
  // cell order: a scan of the box's cells, not of every point. Called
  // outside a parallel region, it scans in parallel (with per-search
  // scratch: not for concurrent calls on one search).
  void dynamicInBox(const AABB<D>& box, std::vector<uint32_t>& out) const;

  VecI<D> cellCoord(const Vec<D>& p) const;
  size_t linearCell(const VecI<D>& c) const {
    size_t l = size_t(c[D - 1]);
    for (int d = D - 2; d >= 0; --d) l = l * size_t(dims_[d]) + size_t(c[d]);
    return l;
  }

 private:
  // Positions in cell order, one array per axis so that the distance test
  // of a row of candidates is a plain loop over floats.
  using SortedCoords = std::array<std::vector<Real>, D>;

  void countingSort(const std::vector<Vec<D>>& x, std::vector<uint32_t>& start, SortedCoords& sorted,
                    std::vector<uint32_t>& sortedIdx, std::vector<uint32_t>& cellOf) const;
  void buildLists(const std::vector<Vec<D>>& x, const std::vector<uint32_t>& start, const SortedCoords& sorted,
                  const std::vector<uint32_t>& sortedIdx, bool excludeSelf, NeighborList& out);

  // g(begin, end) per row of the 3^D cells around p (3^(D-1) rows).
  template <class G>
  void forEachRow(const Vec<D>& p, const std::vector<uint32_t>& start, G& g) const {
    if (start.empty()) return;
    const VecI<D> c = cellCoord(p);
    const int x0 = std::max(c[0] - 1, 0), x1 = std::min(c[0] + 1, dims_[0] - 1);
    auto row = [&](VecI<D> cc) {
      cc[0] = x0;
      const size_t a = linearCell(cc);
      const size_t b = a + size_t(x1 - x0) + 1;
      if (start[a] < start[b]) g(start[a], start[b]);
    };
    if constexpr (D == 2) {
      for (int y = std::max(c[1] - 1, 0); y <= std::min(c[1] + 1, dims_[1] - 1); ++y) row(VecI<D>(0, y));
    } else {
      for (int z = std::max(c[2] - 1, 0); z <= std::min(c[2] + 1, dims_[2] - 1); ++z)
        for (int y = std::max(c[1] - 1, 0); y <= std::min(c[1] + 1, dims_[1] - 1); ++y)
          row(VecI<D>(0, y, z));
    }
  }

  template <class F>
  void forEachNear(const Vec<D>& p, Real r, const std::vector<uint32_t>& start, const SortedCoords& sorted,
                   const std::vector<uint32_t>& idx, F& f) const {
    // A scalar test: it inlines into the solver's boundary sums, where a
    // sixteen-wide one (as control's sums over forEachStaticRange use)
    // measured no faster.
    const Real r2 = r * r;
    auto scan = [&](uint32_t begin, uint32_t end) {
      for (uint32_t k = begin; k < end; ++k) {
        Vec<D> q;
        for (int d = 0; d < D; ++d) q[d] = sorted[d][k];
        if ((q - p).squaredNorm() <= r2) f(idx[k], q);
      }
    };
    forEachRow(p, start, scan);
  }

  AABB<D> domain_;
  Real radius_ = 1, invCell_ = 1;
  VecI<D> dims_ = VecI<D>::Ones();
  size_t cellCount_ = 1;

  std::vector<uint32_t> dynStart_, dynSortedIdx_, dynCellOf_;
  SortedCoords dynSorted_;
  std::vector<uint32_t> statStart_, staticIdx_, statCellOf_;
  SortedCoords staticPos_;

  NeighborList dyn_;
  mutable std::vector<std::pair<uint64_t, uint32_t>> mortonKeys_;  // zOrder's scratch
  std::vector<std::vector<uint32_t>> threadBuf_;  // buildLists' per-thread scan of one particle's candidates
  mutable std::vector<std::vector<uint32_t>> boxBuf_;  // dynamicInBox's per-thread rows
  std::vector<size_t> threadCounts_, regionStart_, regionNeed_;
  std::vector<uint8_t> overflowed_;
};

}  // namespace fc
