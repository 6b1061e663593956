// The grid neighbour search equals brute force, before and after reordering.
#include "core/neighborhood_search.h"
#include "sph/particles.h"
#include <gtest/gtest.h>
#include <omp.h>
#include <algorithm>
#include <random>
#include <set>

using namespace fc;

namespace {

template <int D>
std::vector<std::vector<uint32_t>> bruteForce(const std::vector<Vec<D>>& x, const std::vector<Vec<D>>& y, Real r,
                                              bool excludeSelf) {
  std::vector<std::vector<uint32_t>> out(x.size());
  for (size_t i = 0; i < x.size(); ++i)
    for (size_t j = 0; j < y.size(); ++j)
      if ((!excludeSelf || i != j) && (x[i] - y[j]).squaredNorm() <= r * r) out[i].push_back(uint32_t(j));
  return out;
}

std::vector<std::vector<uint32_t>> fromList(const NeighborList& l, size_t n) {
  std::vector<std::vector<uint32_t>> out(n);
  for (uint32_t i = 0; i < n; ++i) {
    out[i].assign(l.begin(i), l.end(i));
    std::sort(out[i].begin(), out[i].end());
  }
  return out;
}

template <int D>
void checkEqual(const std::vector<Vec<D>>& x, const std::vector<Vec<D>>& statics, const AABB<D>& box, Real r) {
  NeighborhoodSearch<D> ns;
  ns.setGrid(box, r);
  ns.setStaticPoints(statics);
  ns.update(x);
  EXPECT_EQ(fromList(ns.dynamicNeighbors(), x.size()), bruteForce<D>(x, x, r, true));
  NeighborList st;
  ns.staticNeighborLists(x, st);
  EXPECT_EQ(fromList(st, x.size()), bruteForce<D>(x, statics, r, false));

  // Point queries (the vectorised row scan) at the full and at half the
  // radius, and the raw row ranges that vectorised callers scan themselves.
  for (const Real q : {r, r / 2}) {
    const auto dyn = bruteForce<D>(x, x, q, false), stat = bruteForce<D>(x, statics, q, false);
    for (size_t i = 0; i < x.size(); ++i) {
      std::vector<uint32_t> got;
      ns.forEachDynamicNear(x[i], q, [&](uint32_t j, const Vec<D>& xj) {
        EXPECT_EQ(xj, x[j]);
        got.push_back(j);
      });
      std::sort(got.begin(), got.end());
      EXPECT_EQ(got, dyn[i]) << "dynamic query at point " << i;
      got.clear();
      ns.forEachStaticNear(x[i], q, [&](uint32_t j, const Vec<D>&) { got.push_back(j); });
      std::sort(got.begin(), got.end());
      EXPECT_EQ(got, stat[i]) << "static query at point " << i;
      std::vector<uint32_t> inRows;
      ns.forEachStaticRange(x[i], q, [&](uint32_t b, uint32_t e) {
        for (uint32_t k = b; k < e; ++k) {
          Vec<D> s;
          for (int d = 0; d < D; ++d) s[d] = ns.staticSorted(d)[k];
          EXPECT_EQ(s, statics[ns.staticOrder()[k]]);
          inRows.push_back(ns.staticOrder()[k]);
        }
      });
      std::sort(inRows.begin(), inRows.end());
      EXPECT_TRUE(std::includes(inRows.begin(), inRows.end(), stat[i].begin(), stat[i].end()))
          << "a static neighbour of point " << i << " lies outside the scanned rows";
    }
  }

  // Reorder along the Morton curve and search again: same pairs, renamed.
  std::vector<uint32_t> perm;
  ns.zOrder(x, perm);
  ASSERT_EQ(perm.size(), x.size());
  std::vector<uint32_t> sorted = perm;
  std::sort(sorted.begin(), sorted.end());
  for (uint32_t k = 0; k < sorted.size(); ++k) ASSERT_EQ(sorted[k], k) << "not a permutation";
  std::vector<Vec<D>> y = x, scratch;
  applyPermutation(y, perm, scratch);
  ns.update(y);
  EXPECT_EQ(fromList(ns.dynamicNeighbors(), y.size()), bruteForce<D>(y, y, r, true));
  ns.staticNeighborLists(y, st);
  EXPECT_EQ(fromList(st, y.size()), bruteForce<D>(y, statics, r, false));

  // Z-order keeps neighbours close in memory: the mean index distance of
  // neighbour pairs shrinks compared with a random order.
  auto meanGap = [](const NeighborList& l, size_t n) {
    double s = 0;
    for (uint32_t i = 0; i < n; ++i)
      for (const uint32_t* j = l.begin(i); j != l.end(i); ++j) s += std::abs(double(*j) - double(i));
    return s / std::max<size_t>(1, l.pairs());
  };
  const double sortedGap = meanGap(ns.dynamicNeighbors(), y.size());
  std::vector<Vec<D>> shuffled = x;
  std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937(7));
  ns.update(shuffled);
  EXPECT_LT(sortedGap, 0.5 * meanGap(ns.dynamicNeighbors(), shuffled.size()));
}

template <int D>
std::vector<Vec<D>> randomPoints(size_t n, const AABB<D>& box, unsigned seed) {
  std::mt19937 rng(seed);
  std::vector<Vec<D>> p(n);
  for (auto& v : p)
    for (int d = 0; d < D; ++d)
      v[d] = std::uniform_real_distribution<Real>(box.min[d], box.max[d])(rng);
  return p;
}

// Points exactly on cell borders (multiples of the radius) and at exactly the
// search radius from each other: the hardest case for off-by-one errors.
template <int D>
std::vector<Vec<D>> latticePoints(int n, Real spacing) {
  std::vector<Vec<D>> p;
  VecI<D> i = VecI<D>::Zero();
  while (true) {
    p.push_back(spacing * i.template cast<Real>());
    int d = 0;
    while (d < D && ++i[d] == n) i[d++] = 0;
    if (d == D) break;
  }
  return p;
}
}  // namespace

TEST(NeighborhoodSearch, RandomPoints2D) {
  AABB<2> box(Vec<2>(0, 0), Vec<2>(1, 0.7f));
  // Some points outside the grid too: they must still be found.
  auto x = randomPoints<2>(3000, AABB<2>(Vec<2>(-0.1f, -0.1f), Vec<2>(1.1f, 0.8f)), 1);
  checkEqual<2>(x, randomPoints<2>(500, box, 2), box, 0.04f);
}

TEST(NeighborhoodSearch, RandomPoints3D) {
  AABB<3> box(Vec<3>(0, 0, 0), Vec<3>(0.6f, 0.4f, 0.5f));
  auto x = randomPoints<3>(6000, AABB<3>(Vec<3>(-0.05f, 0, 0), Vec<3>(0.65f, 0.45f, 0.5f)), 3);
  checkEqual<3>(x, randomPoints<3>(1000, box, 4), box, 0.05f);
}

TEST(NeighborhoodSearch, LatticeOnCellBorders2D) {
  const Real r = 0.25f;  // = spacing: neighbours at exactly the radius
  auto x = latticePoints<2>(20, r);
  AABB<2> box(Vec<2>(0, 0), Vec<2>(19 * r, 19 * r));
  checkEqual<2>(x, latticePoints<2>(5, 2 * r), box, r);
}

TEST(NeighborhoodSearch, LatticeOnCellBorders3D) {
  const Real r = 0.5f;
  auto x = latticePoints<3>(12, r);
  AABB<3> box(Vec<3>(0, 0, 0), Vec<3>(11 * r, 11 * r, 11 * r));
  checkEqual<3>(x, latticePoints<3>(4, 2 * r), box, r);
}

TEST(NeighborhoodSearch, NonFiniteAndFarPointsDoNotCrash) {
  AABB<2> box(Vec<2>(0, 0), Vec<2>(1, 1));
  std::vector<Vec<2>> x = {Vec<2>(0.5f, 0.5f), Vec<2>(std::nanf(""), 0.2f), Vec<2>(1e30f, -1e30f),
                           Vec<2>(0.51f, 0.5f)};
  NeighborhoodSearch<2> ns;
  ns.setGrid(box, 0.1f);
  ns.update(x);
  EXPECT_EQ(ns.dynamicNeighbors().count(0), 1u);
  EXPECT_EQ(*ns.dynamicNeighbors().begin(0), 3u);
  EXPECT_EQ(ns.dynamicNeighbors().count(1), 0u);  // NaN is nobody's neighbour
}

// The box query returns exactly the points inside the box, each once, in
// cell order; from 4096 candidates on it scans rows in parallel, and the
// result must be the one-thread result, element for element.
template <int D>
void checkBoxQuery(const std::vector<Vec<D>>& x, const AABB<D>& grid, Real r, const AABB<D>& query) {
  NeighborhoodSearch<D> ns;
  ns.setGrid(grid, r);
  ns.update(x);
  std::vector<uint32_t> got;
  ns.dynamicInBox(query, got);
  std::vector<uint32_t> sorted = got, expected;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_TRUE(std::adjacent_find(sorted.begin(), sorted.end()) == sorted.end()) << "a point listed twice";
  for (uint32_t i = 0; i < x.size(); ++i)
    if (query.contains(x[i])) expected.push_back(i);
  EXPECT_EQ(sorted, expected);
  for (size_t k = 1; k < got.size(); ++k)
    ASSERT_LE(ns.linearCell(ns.cellCoord(x[got[k - 1]])), ns.linearCell(ns.cellCoord(x[got[k]])))
        << "not in cell order at " << k;
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  std::vector<uint32_t> serial;
  ns.dynamicInBox(query, serial);
  omp_set_num_threads(threads);
  EXPECT_EQ(got, serial);
}

TEST(NeighborhoodSearch, BoxQueryEqualsBruteForceInCellOrder3D) {
  const AABB<3> grid(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1));
  const auto x = randomPoints<3>(30000, grid, 5);
  checkBoxQuery<3>(x, grid, 0.05f, AABB<3>(Vec<3>(0.1f, 0.05f, 0.2f), Vec<3>(0.9f, 0.8f, 0.95f)));  // rows in parallel
  checkBoxQuery<3>(x, grid, 0.05f, AABB<3>(Vec<3>(0.4f, 0.4f, 0.4f), Vec<3>(0.5f, 0.55f, 0.5f)));   // a few candidates
  checkBoxQuery<3>(x, grid, 0.05f, AABB<3>(Vec<3>(-1, -1, 0.5f), Vec<3>(2, 2, 3)));                 // past the grid
}

TEST(NeighborhoodSearch, BoxQueryEqualsBruteForceInCellOrder2D) {
  const AABB<2> grid(Vec<2>(0, 0), Vec<2>(1, 1));
  const auto x = randomPoints<2>(20000, grid, 6);
  checkBoxQuery<2>(x, grid, 0.02f, AABB<2>(Vec<2>(0.05f, 0.1f), Vec<2>(0.95f, 0.9f)));
  checkBoxQuery<2>(x, grid, 0.02f, AABB<2>(Vec<2>(0.5f, 0.5f), Vec<2>(0.52f, 0.6f)));
}

// The list is written in place, each thread block into a region sized from
// the last build: when the pairs grow eightfold (the region is outgrown and
// the build repeated) or shrink, the list still equals brute force, is the
// same pair for pair on one, two and three threads, and holds no more than
// its largest list and the regions' margins (no second copy of itself).
TEST(NeighborhoodSearch, ManyPointsGetTheSameListsOnAnyThreadCount) {
  // Enough points for every thread to build lists for many regions.
  const AABB<3> box{Vec<3>::Zero(), Vec<3>::Ones()};
  const Real r = Real(0.04);
  const std::vector<Vec<3>> x = randomPoints<3>(90000, box, 5);
  const int threadsBefore = omp_get_max_threads();
  std::vector<uint32_t> offsets, indices;
  for (int threads : {1, 2, 3}) {
    omp_set_num_threads(threads);
    NeighborhoodSearch<3> ns;
    ns.setGrid(box, r);
    ns.update(x);
    const NeighborList& l = ns.dynamicNeighbors();
    const std::vector<uint32_t> o(l.offsets.begin(), l.offsets.begin() + long(x.size()) + 1);
    const std::vector<uint32_t> i(l.indices.begin(), l.indices.begin() + long(l.pairs()));
    if (threads == 1) {
      offsets = o, indices = i;
      // The one-thread lists are right: brute force on a sample of points.
      for (size_t p = 0; p < x.size(); p += 997) {
        std::vector<uint32_t> want, got(l.begin(uint32_t(p)), l.end(uint32_t(p)));
        for (size_t q = 0; q < x.size(); ++q)
          if (q != p && (x[p] - x[q]).squaredNorm() <= r * r) want.push_back(uint32_t(q));
        std::sort(got.begin(), got.end());
        ASSERT_EQ(got, want) << "point " << p;
      }
    } else {
      // The same lists in the same order.
      EXPECT_EQ(o, offsets) << threads << " threads";
      EXPECT_EQ(i, indices) << threads << " threads";
    }
  }
  omp_set_num_threads(threadsBefore);
}

TEST(NeighborhoodSearch, InPlaceListsFollowGrowthAndShrinkOnAnyThreadCount) {
  const AABB<3> box{Vec<3>::Zero(), Vec<3>::Ones()};
  const Real r = Real(0.1);
  const std::vector<Vec<3>> loose = randomPoints<3>(3000, box, 11);
  std::vector<Vec<3>> dense = loose;
  for (auto& p : dense) p *= Real(0.5);
  const int threadsBefore = omp_get_max_threads();
  std::vector<std::vector<uint32_t>> firstRun;
  for (int threads : {1, 2, 3}) {
    omp_set_num_threads(threads);
    NeighborhoodSearch<3> ns;
    ns.setGrid(box, r);
    std::vector<std::vector<uint32_t>> run;
    size_t most = 0;
    const std::vector<Vec<3>>* sets[] = {&loose, &dense, &dense, &loose, &dense};
    for (const std::vector<Vec<3>>* x : sets) {
      ns.update(*x);
      const NeighborList& l = ns.dynamicNeighbors();
      EXPECT_EQ(fromList(l, x->size()), bruteForce<3>(*x, *x, r, true)) << threads << " threads";
      most = std::max(most, l.pairs());
      EXPECT_LE(l.indices.capacity(), most + most / 3 + size_t(threads) * 8192)
          << "the list keeps more than its largest pairs and the regions' margins";
      // Beside the list: the grid's cell starts, the sorted copy (D
      // coordinates, index, cell per point) and a particle's candidates.
      const size_t grid = (ns.cellCount() + 1) * 4 + x->size() * (3 * sizeof(Real) + 8);
      EXPECT_LE(ns.memoryBytes(), l.indices.capacity() * 4 + l.offsets.capacity() * 4 + grid + 64 * 1024)
          << "the search keeps a second copy of its pairs";
      run.emplace_back(l.indices.begin(), l.indices.begin() + long(l.pairs()));
    }
    EXPECT_GT(run[1].size(), 6 * run[0].size()) << "the dense set must outgrow the loose set's regions";
    if (firstRun.empty()) firstRun = run;
    else EXPECT_EQ(run, firstRun) << "the lists differ between 1 and " << threads << " threads";
  }
  omp_set_num_threads(threadsBefore);
}

// One point's list without building every list: the list update() builds,
// pair for pair in its order; after updateGrid() the queries see the new
// positions while the lists stay the last update's.
template <int D>
void checkOnePointLists(const std::vector<Vec<D>>& x, const AABB<D>& box, Real r) {
  NeighborhoodSearch<D> ns;
  ns.setGrid(box, r);
  ns.update(x);
  const NeighborList& lists = ns.dynamicNeighbors();
  std::vector<uint32_t> one;
  for (uint32_t i = 0; i < x.size(); ++i) {
    ns.dynamicNeighborsOf(x[i], i, one);
    ASSERT_EQ(one, std::vector<uint32_t>(lists.begin(i), lists.end(i))) << "point " << i;
  }
  // Every point moved by up to half a radius: the grid follows, the lists do not.
  std::vector<Vec<D>> moved = x;
  std::mt19937 rng(7);
  std::uniform_real_distribution<Real> jitter(-r / 2, r / 2);
  for (auto& p : moved)
    for (int d = 0; d < D; ++d) p[d] += jitter(rng);
  const NeighborList before = lists;
  ns.updateGrid(moved);
  EXPECT_EQ(ns.dynamicNeighbors().offsets, before.offsets);
  EXPECT_TRUE(std::equal(before.begin(0), before.end(uint32_t(x.size() - 1)), ns.dynamicNeighbors().begin(0)));
  const auto truth = bruteForce<D>(moved, moved, r, true);
  for (uint32_t i = 0; i < moved.size(); ++i) {
    ns.dynamicNeighborsOf(moved[i], i, one);
    std::sort(one.begin(), one.end());
    ASSERT_EQ(one, truth[i]) << "point " << i << " after updateGrid";
  }
  // And the lists a full update then builds are the one-point ones.
  ns.update(moved);
  for (uint32_t i = 0; i < moved.size(); ++i) {
    ns.dynamicNeighborsOf(moved[i], i, one);
    ASSERT_EQ(one, std::vector<uint32_t>(ns.dynamicNeighbors().begin(i), ns.dynamicNeighbors().end(i)));
  }
}

TEST(NeighborhoodSearch, OnePointsListIsTheOneUpdateBuilds2D) {
  AABB<2> box(Vec<2>(0, 0), Vec<2>(1, 0.7f));
  checkOnePointLists<2>(randomPoints<2>(3000, AABB<2>(Vec<2>(-0.1f, -0.1f), Vec<2>(1.1f, 0.8f)), 11), box, 0.04f);
  checkOnePointLists<2>(latticePoints<2>(20, 0.25f), AABB<2>(Vec<2>(0, 0), Vec<2>(4.75f, 4.75f)), 0.25f);
}

TEST(NeighborhoodSearch, OnePointsListIsTheOneUpdateBuilds3D) {
  AABB<3> box(Vec<3>(0, 0, 0), Vec<3>(0.6f, 0.4f, 0.5f));
  checkOnePointLists<3>(randomPoints<3>(6000, AABB<3>(Vec<3>(-0.05f, 0, 0), Vec<3>(0.65f, 0.45f, 0.5f)), 13), box,
                        0.05f);
  checkOnePointLists<3>(latticePoints<3>(12, 0.5f), AABB<3>(Vec<3>(0, 0, 0), Vec<3>(5.5f, 5.5f, 5.5f)), 0.5f);
}

// Points piled into one spot (a simulation that blew up) are reported, not
// listed: listing them would take n² time and memory. The search then lists
// an ordinary set again.
template <int D>
void checkPileIsReported(int piled) {
  const Real h = 0.05f;
  AABB<D> box;
  box.min = Vec<D>::Zero();
  box.max = Vec<D>::Constant(Real(0.6));
  std::vector<Vec<D>> pile(size_t(piled), Vec<D>::Constant(Real(0.3)));
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> jitter(-1e-4f, 1e-4f);
  for (auto& p : pile)
    for (int d = 0; d < D; ++d) p[d] += jitter(rng);
  NeighborhoodSearch<D> search;
  search.setGrid(box, h);
  try {
    search.update(pile);
    FAIL() << "a pile of " << piled << " points was listed";
  } catch (const NeighborCollapse& e) {
    EXPECT_NE(std::string(e.what()).find("collapsed"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(std::to_string(piled) + " particles in one's neighbourhood"), std::string::npos) << e.what();
  }
  EXPECT_EQ(search.dynamicNeighbors().pairs(), 0u);
  for (size_t i = 0; i < pile.size(); i += 997) EXPECT_EQ(search.dynamicNeighbors().count(uint32_t(i)), 0u);

  const std::vector<Vec<D>> lattice = latticePoints<D>(D == 3 ? 10 : 40, Real(0.5) * h);
  search.update(lattice);
  size_t pairs = 0;
  for (size_t i = 0; i < lattice.size(); ++i)
    for (size_t j = 0; j < lattice.size(); ++j)
      pairs += i != j && (lattice[i] - lattice[j]).squaredNorm() <= h * h;
  EXPECT_EQ(search.dynamicNeighbors().pairs(), pairs);
}

TEST(NeighborhoodSearch, APileOfPointsIsReportedNotListed2D) { checkPileIsReported<2>(9000); }
TEST(NeighborhoodSearch, APileOfPointsIsReportedNotListed3D) { checkPileIsReported<3>(40000); }
