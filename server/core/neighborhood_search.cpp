#include "core/neighborhood_search.h"

#include "core/parallel_failure.h"
#include "core/morton.h"
#include "core/capacity_bytes.h"
#include <omp.h>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif
#include <type_traits>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <stdexcept>

namespace fc {

template <int D>
void NeighborhoodSearch<D>::setGrid(const AABB<D>& domain, Real radius) {
  if (!(radius > 0)) throw std::invalid_argument("neighbour search radius must be positive");
  radius_ = radius;
  invCell_ = Real(1) / radius;
  // One spare cell on each side so that particles slightly outside the domain
  // still fall in distinct cells.
  domain_ = domain.grown(radius);
  double cells = 1;
  for (int d = 0; d < D; ++d) {
    dims_[d] = std::max(1, int(std::ceil(domain_.size()[d] * invCell_)));
    cells *= dims_[d];
  }
  if (cells > 2.0e8)
    throw std::invalid_argument("domain too large for the particle size: the neighbour grid would need " +
                                std::to_string(size_t(cells)) + " cells");
  cellCount_ = size_t(cells);
  dynStart_.clear();
  statStart_.clear();
  staticIdx_.clear();
  for (auto& s : staticPos_) s.clear();
}

template <int D>
VecI<D> NeighborhoodSearch<D>::cellCoord(const Vec<D>& p) const {
  VecI<D> c;
  for (int d = 0; d < D; ++d) {
    Real f = (p[d] - domain_.min[d]) * invCell_;
    // NaN and far-away points land in border cells instead of overflowing.
    if (!(f >= 0)) f = 0;
    c[d] = std::min(int(std::min(f, Real(1e9))), dims_[d] - 1);
  }
  return c;
}

template <int D>
void NeighborhoodSearch<D>::countingSort(const std::vector<Vec<D>>& x, std::vector<uint32_t>& start,
                                         SortedCoords& sorted, std::vector<uint32_t>& sortedIdx,
                                         std::vector<uint32_t>& cellOf) const {
  const size_t n = x.size();
  cellOf.resize(n);
  for (auto& s : sorted) s.resize(n);
  sortedIdx.resize(n);
  start.assign(cellCount_ + 1, 0);
#pragma omp parallel for schedule(static)
  for (size_t i = 0; i < n; ++i) cellOf[i] = uint32_t(linearCell(cellCoord(x[i])));
  for (size_t i = 0; i < n; ++i) ++start[cellOf[i] + 1];
  std::partial_sum(start.begin(), start.end(), start.begin());
  // Scatter in particle order, so the result is deterministic.
  for (size_t i = 0; i < n; ++i) sortedIdx[start[cellOf[i]]++] = uint32_t(i);
  // start[c] now holds the end of cell c: shift back by one cell.
  for (size_t c = cellCount_; c > 0; --c) start[c] = start[c - 1];
  start[0] = 0;
#pragma omp parallel for schedule(static)
  for (size_t k = 0; k < n; ++k)
    for (int d = 0; d < D; ++d) sorted[d][k] = x[sortedIdx[k]][d];
}

namespace {

// A sixteen-wide step stores all sixteen lanes, up to 15 past its last hit.
constexpr size_t kScanSlack = 16;

// Candidates (the points of a particle's 3^D cells) beyond which the points
// have collapsed: a liquid at rest has about 220 (3D) or 36 (2D) there, and
// a list built from such a pile would take O(n²) time and memory.
template <int D>
constexpr size_t kCollapsedCandidates = D == 3 ? 32768 : 8192;

// Writes the indices of the candidates k in [begin, end) within sqrt(r2) of p
// (except `self`) to dst and returns how many. dst must have room for every
// candidate plus kScanSlack: misses are written too, only the cursor skips
// them.
template <int D>
size_t scanRow(const std::array<std::vector<Real>, D>& sorted, const uint32_t* sortedIdx, uint32_t begin,
               uint32_t end, const Vec<D>& p, Real r2, uint32_t self, uint32_t* dst) {
  size_t hits = 0;
  uint32_t k = begin;
#if defined(__AVX512F__)
  if constexpr (std::is_same_v<Real, float>) {
    // Sixteen candidates per step; the hits are packed in a register and all
    // sixteen lanes stored. The compress-to-memory form (vpcompressd m512) is
    // microcoded on some processors (AMD Zen 4), where it made this search
    // several times slower; the register form is fast everywhere.
    __m512 pv[D];
    for (int d = 0; d < D; ++d) pv[d] = _mm512_set1_ps(p[d]);
    const __m512 r2v = _mm512_set1_ps(r2);
    const __m512i selfv = _mm512_set1_epi32(int(self));
    for (; k < end; k += 16) {
      const __mmask16 live = end - k >= 16 ? __mmask16(0xffff) : __mmask16((1u << (end - k)) - 1);
      __m512 d2 = _mm512_setzero_ps();
      for (int d = 0; d < D; ++d) {
        const __m512 dd = _mm512_sub_ps(_mm512_maskz_loadu_ps(live, sorted[d].data() + k), pv[d]);
        d2 = _mm512_fmadd_ps(dd, dd, d2);
      }
      const __m512i idx = _mm512_maskz_loadu_epi32(live, sortedIdx + k);
      const __mmask16 m = _mm512_mask_cmp_ps_mask(live, d2, r2v, _CMP_LE_OQ) &
                          ~_mm512_cmpeq_epi32_mask(idx, selfv);
      _mm512_storeu_si512(dst + hits, _mm512_maskz_compress_epi32(m, idx));
      hits += size_t(__builtin_popcount(unsigned(m)));
    }
    return hits;
  }
#endif
  for (; k < end; ++k) {
    Real d2 = 0;
    for (int d = 0; d < D; ++d) {
      const Real dd = sorted[d][k] - p[d];
      d2 += dd * dd;
    }
    const uint32_t j = sortedIdx[k];
    dst[hits] = j;
    hits += (d2 <= r2) & (j != self);
  }
  return hits;
}

}  // namespace

template <int D>
void NeighborhoodSearch<D>::buildLists(const std::vector<Vec<D>>& x, const std::vector<uint32_t>& start,
                                       const SortedCoords& sorted, const std::vector<uint32_t>& sortedIdx,
                                       bool excludeSelf, NeighborList& out) {
  const size_t n = x.size();
  out.offsets.resize(n + 1);
  const int maxThreads = omp_get_max_threads();
  if (int(threadBuf_.size()) < maxThreads) threadBuf_.resize(maxThreads);
  threadCounts_.assign(size_t(maxThreads) + 1, 0);
  regionNeed_.assign(size_t(maxThreads), 0);
  overflowed_.assign(size_t(maxThreads), 0);
  const Real r2 = radius_ * radius_;
  const bool haveTargets = !sortedIdx.empty();
  // Each thread block writes into its own region of out.indices, sized from
  // the last build's pairs with a margin; a block that outgrows its region
  // only counts, and the build is repeated with regions of the counts.
  std::vector<size_t>& last = out.blockPairs;
  auto planRegions = [&](int teams, bool exact) {
    regionStart_.assign(size_t(teams) + 1, 0);
    for (int t = 0; t < teams; ++t) {
      const size_t base = exact ? regionNeed_[size_t(t)] : last.size() == size_t(teams) ? last[size_t(t)] : 0;
      regionStart_[size_t(t) + 1] = regionStart_[size_t(t)] + base + base / 8 + 4096 + kScanSlack;
    }
    const size_t want = regionStart_.back();
    // The old pairs are not needed: a list that must grow is freed before it
    // is allocated again, never copied (which would hold both at once), and
    // with an eighth to spare, so that a slowly growing list is not
    // allocated again at every build.
    if (want > out.indices.size()) {
      out.indices = {};
      out.indices.resize(want + want / 8);
    }
    // What the regions leave is shared out among them.
    const size_t spare = (out.indices.size() - want) / size_t(teams);
    for (int t = 1; t <= teams; ++t) regionStart_[size_t(t)] += spare * size_t(t);
    regionStart_.back() = out.indices.size();
  };
  int teams = 0;
  bool exact = false;
  // Regions of the counts cannot be outgrown by the same team: the second
  // pass is the last (unless the team's size changed in between).
  ParallelFailure failure;  // an exception in the region (no memory for the list), rethrown after it
  size_t crowded = 0;       // the most candidates of a particle past kCollapsedCandidates, 0 if none
  size_t total = 0;         // the pairs of the last pass
  bool failed = false;      // no list: out of memory, or a pile
  for (;;) {
    bool anyOverflow = false;
#pragma omp parallel
    {
      const int t = omp_get_thread_num(), T = omp_get_num_threads();
#pragma omp single
      {
        teams = T;
        try {
          planRegions(T, exact);
        } catch (...) {
          failure.keep();
          failed = true;
        }
      }
      if (!failed) {  // every thread sees it after the single's barrier
        const size_t begin = n * size_t(t) / size_t(T), end = n * size_t(t + 1) / size_t(T);
        uint32_t* region = out.indices.data() + regionStart_[size_t(t)];
        const size_t room = regionStart_[size_t(t) + 1] - regionStart_[size_t(t)];
        std::vector<uint32_t>& scratch = threadBuf_[t];
        bool overflow = false;
        size_t used = 0, most = 0, mostCrowded = 0;
        constexpr int rows = D == 2 ? 3 : 9;
        std::array<uint32_t, rows> rowBegin{}, rowEnd{};
        for (size_t i = begin; i < end; ++i) {
          out.offsets[i] = uint32_t(used);
          if (!haveTargets) continue;
          const Vec<D> p = x[i];
          int nrows = 0;
          size_t candidates = 0;
          auto addRow = [&](uint32_t rb, uint32_t re) {
            rowBegin[nrows] = rb;
            rowEnd[nrows] = re;
            candidates += re - rb;
            ++nrows;
          };
          forEachRow(p, start, addRow);
          if (candidates > kCollapsedCandidates<D>) {
            mostCrowded = std::max(mostCrowded, candidates);
            continue;
          }
          most = std::max(most, candidates);
          // Room for every candidate, so the scan can write each one and
          // advance the cursor only for hits, without a branch.
          overflow = overflow || used + candidates + kScanSlack > room;
          uint32_t* dst;
          if (!overflow) {
            dst = region + used;
          } else {
            if (scratch.size() < candidates + kScanSlack) scratch.resize(candidates + kScanSlack);
            dst = scratch.data();
          }
          size_t hits = 0;
          for (int rr = 0; rr < nrows; ++rr)
            hits += scanRow<D>(sorted, sortedIdx.data(), rowBegin[rr], rowEnd[rr], p, r2,
                               excludeSelf ? uint32_t(i) : UINT32_MAX, dst + hits);
          used += hits;
        }
        threadCounts_[size_t(t) + 1] = used;
        regionNeed_[size_t(t)] = used + most + kScanSlack;
        overflowed_[size_t(t)] = overflow;
        if (mostCrowded > 0) {
#pragma omp critical(fc_neighbor_crowded)
          crowded = std::max(crowded, mostCrowded);
        }
#pragma omp barrier
#pragma omp single
        {
          for (int k = 0; k < T; ++k) anyOverflow = anyOverflow || overflowed_[size_t(k)];
          total = 0;
          for (int k = 0; k < T; ++k) total += threadCounts_[size_t(k) + 1];
          // The offsets are 32-bit: a list past them cannot be stored.
          failed = crowded > 0 || total > UINT32_MAX;
          if (!anyOverflow && !failed) {
            // Close the gaps between the regions, in order: each block moves
            // towards the front, never over a block still to be moved.
            for (int k = 0; k < T; ++k) {
              threadCounts_[size_t(k) + 1] += threadCounts_[size_t(k)];
              const size_t to = threadCounts_[size_t(k)], from = regionStart_[size_t(k)];
              const size_t count = threadCounts_[size_t(k) + 1] - to;
              if (count && to != from)
                std::memmove(out.indices.data() + to, out.indices.data() + from, count * sizeof(uint32_t));
            }
            out.offsets[n] = uint32_t(threadCounts_[size_t(T)]);
          }
        }
        if (!anyOverflow && !failed) {
          const uint32_t base = uint32_t(threadCounts_[size_t(t)]);
          for (size_t i = begin; i < end; ++i) out.offsets[i] += base;
        }
      }
    }
    if (failed) break;
    if (!anyOverflow) break;
    exact = true;
  }
  if (failed) {
    // Nothing may read a half-built list: an empty one.
    std::fill(out.offsets.begin(), out.offsets.end(), 0u);
    out.blockPairs.clear();
    failure.rethrow();
    throw NeighborCollapse(crowded > 0 ? std::to_string(crowded) + " particles in one's neighbourhood, where a liquid "
                                                                    "at rest has a few hundred"
                                       : std::to_string(total) + " neighbour pairs, more than 2^32");
  }
  last.assign(size_t(teams), 0);
  for (int t = 0; t < teams; ++t) last[size_t(t)] = threadCounts_[size_t(t) + 1] - threadCounts_[size_t(t)];
}

template <int D>
size_t NeighborhoodSearch<D>::memoryBytes() const {
  const auto bytes = [](const auto& v) { return capacityBytes(v); };
  size_t b = bytes(dynStart_) + bytes(dynSortedIdx_) + bytes(dynCellOf_) + bytes(statStart_) + bytes(staticIdx_) +
             bytes(statCellOf_) + bytes(dyn_.offsets) + bytes(dyn_.indices) + bytes(dyn_.blockPairs) +
             bytes(mortonKeys_) + bytes(threadCounts_) + bytes(regionStart_) + bytes(regionNeed_) + bytes(overflowed_);
  for (int d = 0; d < D; ++d) b += bytes(dynSorted_[d]) + bytes(staticPos_[d]);
  for (const auto& v : threadBuf_) b += bytes(v);
  for (const auto& v : boxBuf_) b += bytes(v);
  return b;
}

template <int D>
void NeighborhoodSearch<D>::dynamicInBox(const AABB<D>& box, std::vector<uint32_t>& out) const {
  out.clear();
  if (dynStart_.empty() || box.empty()) return;
  const VecI<D> lo = cellCoord(box.min), hi = cellCoord(box.max);
  // One row along x is one contiguous range of the sorted points; rows are
  // numbered y-fastest (then z).
  long rows = 1;
  for (int d = 1; d < D; ++d) rows *= long(hi[d] - lo[d] + 1);
  auto scanRow = [&](long r, std::vector<uint32_t>& dst) {
    VecI<D> c = lo;
    for (int d = 1; d < D; ++d) {
      const long span = long(hi[d] - lo[d] + 1);
      c[d] = lo[d] + int(r % span);
      r /= span;
    }
    const size_t a = linearCell(c);
    const size_t b = a + size_t(hi[0] - lo[0]) + 1;
    for (uint32_t k = dynStart_[a]; k < dynStart_[b]; ++k) {
      bool inside = true;
      for (int d = 0; d < D; ++d) inside = inside && dynSorted_[d][k] >= box.min[d] && dynSorted_[d][k] <= box.max[d];
      if (inside) dst.push_back(dynSortedIdx_[k]);
    }
  };
  // Many candidates: the rows in one block per thread, concatenated in
  // thread order, which is the row order of the serial scan.
  const size_t candidates = dynStart_[linearCell(hi) + 1] - dynStart_[linearCell(lo)];
  const int threads = omp_get_max_threads();
  if (candidates < 4096 || threads < 2 || rows < 2 * threads || omp_in_parallel()) {
    for (long r = 0; r < rows; ++r) scanRow(r, out);
    return;
  }
  if (int(boxBuf_.size()) < threads) boxBuf_.resize(size_t(threads));
#pragma omp parallel num_threads(threads)
  {
    std::vector<uint32_t>& mine = boxBuf_[size_t(omp_get_thread_num())];
    mine.clear();
#pragma omp for schedule(static)
    for (long r = 0; r < rows; ++r) scanRow(r, mine);
  }
  for (int t = 0; t < threads; ++t) out.insert(out.end(), boxBuf_[size_t(t)].begin(), boxBuf_[size_t(t)].end());
}

template <int D>
void NeighborhoodSearch<D>::setStaticPoints(const std::vector<Vec<D>>& points) {
  countingSort(points, statStart_, staticPos_, staticIdx_, statCellOf_);
}

template <int D>
void NeighborhoodSearch<D>::update(const std::vector<Vec<D>>& x) {
  countingSort(x, dynStart_, dynSorted_, dynSortedIdx_, dynCellOf_);
  buildLists(x, dynStart_, dynSorted_, dynSortedIdx_, true, dyn_);
}

template <int D>
void NeighborhoodSearch<D>::updateGrid(const std::vector<Vec<D>>& x) {
  countingSort(x, dynStart_, dynSorted_, dynSortedIdx_, dynCellOf_);
}

template <int D>
void NeighborhoodSearch<D>::dynamicNeighborsOf(const Vec<D>& p, uint32_t self, std::vector<uint32_t>& out) const {
  // The rows and the scan buildLists uses, so the list is the same one.
  size_t candidates = 0;
  auto count = [&](uint32_t b, uint32_t e) { candidates += e - b; };
  forEachRow(p, dynStart_, count);
  out.resize(candidates + kScanSlack);
  size_t hits = 0;
  const Real r2 = radius_ * radius_;
  auto scan = [&](uint32_t b, uint32_t e) {
    hits += scanRow<D>(dynSorted_, dynSortedIdx_.data(), b, e, p, r2, self, out.data() + hits);
  };
  forEachRow(p, dynStart_, scan);
  out.resize(hits);
}

template <int D>
void NeighborhoodSearch<D>::staticNeighborLists(const std::vector<Vec<D>>& x, NeighborList& out) {
  if (statStart_.empty()) {
    out.offsets.assign(x.size() + 1, 0);
    out.indices.clear();
    return;
  }
  buildLists(x, statStart_, staticPos_, staticIdx_, false, out);
}

template <int D>
void NeighborhoodSearch<D>::zOrder(const std::vector<Vec<D>>& x, std::vector<uint32_t>& perm) const {
  const size_t n = x.size();
  auto& keys = mortonKeys_;
  keys.resize(n);
#pragma omp parallel for schedule(static)
  for (size_t i = 0; i < n; ++i) {
    const VecI<D> c = cellCoord(x[i]);
    uint64_t code;
    if constexpr (D == 2) code = morton2(uint32_t(c[0]), uint32_t(c[1]));
    else code = morton3(uint32_t(c[0]), uint32_t(c[1]), uint32_t(c[2]));
    keys[i] = {code, uint32_t(i)};
  }
  std::sort(keys.begin(), keys.end());
  perm.resize(n);
  for (size_t k = 0; k < n; ++k) perm[k] = keys[k].second;
}

FC_INSTANTIATE_DIMS(NeighborhoodSearch)

}  // namespace fc
