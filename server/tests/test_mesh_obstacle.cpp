// Mesh obstacles: the OBJ reader and its validation, the signed distance
// (exact and gridded) against analytic shapes and a brute-force reference,
// the boundary sampling, scene parsing and a small 3D dam break against a
// mesh box compared with the same box as an analytic obstacle.
#include "io/obj_mesh.h"
#include "io/scene.h"
#include "physics_checks.h"
#include "sph/sampling/boundary.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <random>

namespace fc {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

std::string testMeshes() { return std::string(FLOWCLIP_SOURCE_DIR) + "/server/tests/meshes"; }
std::string badScenes() { return std::string(FLOWCLIP_SOURCE_DIR) + "/server/tests/bad_scenes"; }

// A scratch directory for OBJ files written by the tests.
struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / ("flowclip_mesh_test_" + std::to_string(getpid()));
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  std::string write(const std::string& name, const std::string& text) const {
    const fs::path f = path / name;
    std::ofstream(f) << text;
    return f.string();
  }
};

const char* kCubeVertices =
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n";
const char* kCubeFaces = "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\n";

double boxDistance(const Vec3d& p, const Vec3d& lo, const Vec3d& hi) {
  const Vec3d c = 0.5 * (lo + hi), h = 0.5 * (hi - lo);
  const Vec3d q = (p - c).cwiseAbs() - h;
  return q.cwiseMax(Vec3d::Zero()).norm() + std::min(q.maxCoeff(), 0.0);
}

// ------------------------------------------------------------- reading ---

TEST(ObjMesh, CubeWithQuadsAndAttributesParsesToTwelveTriangles) {
  const ObjSolid s = readObjSolid(testMeshes() + "/cube_quads.obj");
  EXPECT_EQ(s.mesh.triangles.size(), 12u);
  EXPECT_EQ(s.mesh.vertices.size(), 8u);
  EXPECT_EQ(s.polygons, 6u);
  EXPECT_FALSE(s.flipped);
  EXPECT_NEAR(s.mesh.signedVolume(), 1.0, 1e-12);
  const AABB<3> b = s.mesh.bounds();
  EXPECT_EQ(b.min, Vec3::Constant(-0.5f));
  EXPECT_EQ(b.max, Vec3::Constant(0.5f));
}

TEST(ObjMesh, InsideOutCubeIsFlipped) {
  ObjSolid s = readObjSolid(testMeshes() + "/cube_inside_out.obj");
  EXPECT_TRUE(s.flipped);
  EXPECT_NEAR(s.mesh.signedVolume(), 1.0, 1e-12);
  const MeshSdf sdf(std::move(s.mesh), {0.05, 0.1});
  EXPECT_NEAR(sdf.signedDistance(Vec3::Zero()), -0.5, 1e-6);
  EXPECT_NEAR(sdf.exactSignedDistance(Vec3d(0.1, 0.2, -0.1)), -0.3, 1e-12);
  EXPECT_NEAR(sdf.signedDistance(Vec3(0.7f, 0, 0)), 0.2, 1e-6);
}

TEST(ObjMesh, CoincidentVerticesAreMerged) {
  // Every face with its own four vertices (as some exporters write it).
  TempDir tmp;
  const Vec3d c[8] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
  const int faces[6][4] = {{1, 4, 3, 2}, {5, 6, 7, 8}, {1, 2, 6, 5}, {4, 8, 7, 3}, {1, 5, 8, 4}, {2, 3, 7, 6}};
  std::string text;
  for (int f = 0; f < 6; ++f)
    for (int k = 0; k < 4; ++k) {
      const Vec3d& v = c[faces[f][k] - 1];
      text += "v " + std::to_string(v[0]) + " " + std::to_string(v[1]) + " " + std::to_string(v[2]) + "\n";
    }
  for (int f = 0; f < 6; ++f)
    text += "f " + std::to_string(4 * f + 1) + " " + std::to_string(4 * f + 2) + " " + std::to_string(4 * f + 3) + " " +
            std::to_string(4 * f + 4) + "\n";
  const ObjSolid s = readObjSolid(tmp.write("split.obj", text));
  EXPECT_EQ(s.mesh.vertices.size(), 8u);
  EXPECT_EQ(s.mergedVertices, 16u);
  EXPECT_EQ(s.mesh.triangles.size(), 12u);
}

// Expects readObjSolid to fail with every string of `mentions` in the message.
void expectObjError(const std::string& file, const std::vector<std::string>& mentions) {
  try {
    readObjSolid(file);
    ADD_FAILURE() << file << " was accepted";
  } catch (const MeshFileError& e) {
    const std::string what = e.what();
    for (const auto& m : mentions) EXPECT_NE(what.find(m), std::string::npos) << "'" << m << "' missing in: " << what;
  }
}

TEST(ObjMesh, BadInputIsRefusedWithFileLineAndReason) {
  TempDir tmp;
  const std::string v = kCubeVertices, f = kCubeFaces;
  expectObjError(tmp.write("word.obj", v + "f 1 2 x\n" + f), {"word.obj:9:", "'x' is not a vertex reference"});
  expectObjError(tmp.write("short_v.obj", "v 1 2\n"), {"short_v.obj:1:", "3 coordinates"});
  expectObjError(tmp.write("inf.obj", "v 1 inf 2\n"), {"inf.obj:1:", "non-finite"});
  expectObjError(tmp.write("huge.obj", "v 1 1e999 2\n"), {"huge.obj:1:", "non-finite"});
  expectObjError(tmp.write("zero.obj", v + "f 0 1 2\n"), {"zero.obj:9:", "start at 1"});
  expectObjError(tmp.write("neg.obj", "v 0 0 0\nf -1 -2 -3\n"), {"neg.obj:2:", "-2 is out of range"});
  expectObjError(tmp.write("big.obj", v + f + "f 1 2 99\n"), {"big.obj:15:", "vertex index 99 is out of range", "8 vertices"});
  expectObjError(tmp.write("line.obj", v + "l 1 2\n" + f), {"line.obj:9:", "unsupported OBJ statement 'l'"});
  expectObjError(tmp.write("two.obj", v + "f 1 2\n"), {"two.obj:9:", "at least 3 vertices"});
  expectObjError(tmp.write("few.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 2\n"), {"at least 4 vertices and 4 triangles"});
  expectObjError(tmp.write("degenerate.obj", v + "v 0.5 0 0\n" + f + "f 1 9 2\n"), {"degenerate.obj:16:", "degenerate triangle"});
  // A face listed twice: its edges are shared by three faces.
  expectObjError(tmp.write("crowded.obj", v + f + "f 2 3 7 6\n"), {"shared by more than two faces"});
  // One face turned over.
  std::string turned = f;
  turned.replace(turned.find("f 2 3 7 6"), 9, "f 6 7 3 2");
  expectObjError(tmp.write("turned.obj", v + turned), {"not consistently oriented", "the faces at lines"});
  expectObjError(tmp.path.string() + "/nothing.obj", {"does not exist"});
}

TEST(ObjMesh, OpenBoxNamesAnOpenEdge) {
  expectObjError(badScenes() + "/meshes/open_box.obj",
                 {"open_box.obj: the mesh is not closed: 4 edges belong to one face only", "e.g. the edge from vertex",
                  "has no other face"});
}

// ------------------------------------------------------ signed distance ---

// Independent reference: distance to each triangle (projection, else the
// nearest edge), sign from the generalized winding number (solid angles).
double bruteSignedDistance(const TriangleMesh& m, const Vec3d& p) {
  auto segment = [](const Vec3d& p, const Vec3d& a, const Vec3d& b) {
    const double t = std::clamp((p - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
    return (p - (a + t * (b - a))).norm();
  };
  double best = std::numeric_limits<double>::infinity(), winding = 0;
  for (const auto& t : m.triangles) {
    const Vec3d &a = m.vertices[t[0]], &b = m.vertices[t[1]], &c = m.vertices[t[2]];
    const Vec3d n = (b - a).cross(c - a).normalized();
    const Vec3d q = p - n * n.dot(p - a);
    const double w0 = (b - q).cross(c - q).dot(n), w1 = (c - q).cross(a - q).dot(n), w2 = (a - q).cross(b - q).dot(n);
    double d = (w0 >= 0 && w1 >= 0 && w2 >= 0) ? std::abs(n.dot(p - a))
                                               : std::min({segment(p, a, b), segment(p, b, c), segment(p, c, a)});
    best = std::min(best, d);
    const Vec3d x = a - p, y = b - p, z = c - p;
    const double lx = x.norm(), ly = y.norm(), lz = z.norm();
    winding += 2 * std::atan2(x.dot(y.cross(z)), lx * ly * lz + x.dot(y) * lz + y.dot(z) * lx + z.dot(x) * ly);
  }
  return winding / (4 * std::numbers::pi) > 0.5 ? -best : best;
}

// An icosphere of radius 1, `levels` times subdivided, as OBJ text.
std::string icosphereObj(int levels) {
  const double g = (1 + std::sqrt(5.0)) / 2;
  std::vector<Vec3d> v = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0}, {0, -1, g}, {0, 1, g},
                          {0, -1, -g}, {0, 1, -g}, {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
  for (auto& x : v) x.normalize();
  std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                                       {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
                                       {3, 8, 9},  {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      const auto k = std::minmax(a, b);
      auto it = mid.find(k);
      if (it != mid.end()) return it->second;
      v.push_back((v[size_t(a)] + v[size_t(b)]).normalized());
      return mid[k] = int(v.size()) - 1;
    };
    std::vector<std::array<int, 3>> next;
    for (const auto& t : f) {
      const int a = midpoint(t[0], t[1]), b = midpoint(t[1], t[2]), c = midpoint(t[2], t[0]);
      next.push_back({t[0], a, c});
      next.push_back({t[1], b, a});
      next.push_back({t[2], c, b});
      next.push_back({a, b, c});
    }
    f = next;
  }
  std::ostringstream s;
  s.precision(17);
  for (const auto& x : v) s << "v " << x[0] << " " << x[1] << " " << x[2] << "\n";
  for (const auto& t : f) s << "f " << t[0] + 1 << " " << t[1] + 1 << " " << t[2] + 1 << "\n";
  return s.str();
}

TEST(MeshSdf, BoxMeshMatchesTheAnalyticBoxDistance) {
  // The unit cube scaled to 0.2 x 0.4 x 0.3 m, at r = 0.02 m.
  ObjSolid s = readObjSolid(testMeshes() + "/cube_quads.obj");
  const Vec3d size(0.2, 0.4, 0.3), center(0.5, 0.3, 0.2);
  for (Vec3d& v : s.mesh.vertices) v = size.cwiseProduct(v) + center;
  const double h = 0.02;
  const MeshSdf sdf(s.mesh, {h, 5 * h});
  const Vec3d lo = center - 0.5 * size, hi = center + 0.5 * size;
  std::mt19937 rng(7);
  const AABB<3> grid = sdf.gridBox();  // points up to 0.1 m beyond it too
  std::uniform_real_distribution<double> ux(grid.min[0] - 0.1, grid.max[0] + 0.1), uy(grid.min[1] - 0.1, grid.max[1] + 0.1),
      uz(grid.min[2] - 0.1, grid.max[2] + 0.1);
  // Trilinear interpolation is exact where the distance is linear (beside a
  // face) and errs where it bends: outside along edges and corners (a
  // Euclidean distance, convex: the grid overestimates) and inside across
  // the medial planes (a max of the face distances, with a kink).
  double maxExact = 0, maxOutside = 0, maxInside = 0, maxFace = 0;
  for (int k = 0; k < 20000; ++k) {
    const Vec3d p(ux(rng), uy(rng), uz(rng));
    const double ref = boxDistance(p, lo, hi);
    maxExact = std::max(maxExact, std::abs(sdf.exactSignedDistance(p) - ref));
    const double grid = double(sdf.gridSignedDistance(p.cast<Real>()));
    if (!sdf.gridBox().contains(p.cast<Real>())) {
      // Outside the grid the value is an upper bound, positive.
      EXPECT_GE(grid, ref - 1e-5);
      continue;
    }
    const double err = std::abs(grid - ref);
    (ref >= 0 ? maxOutside : maxInside) = std::max(ref >= 0 ? maxOutside : maxInside, err);
    // Beside a face: within a cell of it (inside or out), over its part
    // more than 3 cells from its edges.
    const Vec3d q = (p - center).cwiseAbs() - 0.5 * size;
    int beside = 0;
    for (int d = 0; d < 3; ++d) beside += q[d] > -3 * h ? 1 : 0;
    if (beside == 1 && std::abs(ref) < h) maxFace = std::max(maxFace, err);
  }
  EXPECT_LT(maxExact, 1e-12);
  EXPECT_LT(maxFace, 1e-4 * h) << "beside a face the distance is linear: trilinear is exact";
  // At a corner the 8 nodes around it average 0.5 h (trilinear rounds a
  // convex corner by about half a cell); inside, a cell across a medial
  // plane errs by up to 3/8 h, more where three meet.
  EXPECT_LT(maxOutside, 0.55 * h) << "outside, along edges and corners";
  EXPECT_LT(maxInside, 0.55 * h) << "inside, across the medial planes";
  if (verbose())
    std::printf("box mesh, h = %g: exact error %.2e m; grid error beside faces %.2e h, outside %.3f h, inside %.3f h; "
                "%zu nodes in %.1f ms\n",
                h, maxExact, maxFace / h, maxOutside / h, maxInside / h, sdf.nodes(), sdf.buildMs());
}

TEST(MeshSdf, IcosphereMatchesBruteForceAndTheSphere) {
  TempDir tmp;
  ObjSolid s = readObjSolid(tmp.write("ico.obj", icosphereObj(2)));  // 320 triangles
  ASSERT_EQ(s.mesh.triangles.size(), 320u);
  for (Vec3d& v : s.mesh.vertices) v *= 0.2;
  const double h = 0.01;
  const MeshSdf sdf(s.mesh, {h, 5 * h});
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  // Nodes nearer than 4 cells to the surface are exact; the far field is
  // interpolated from a grid 4 times coarser (the sign is right, the value
  // within a few cells).
  double maxExact = 0, maxNear = 0, maxFar = 0;
  bool signsAgree = true;
  for (int k = 0; k < 3000; ++k) {
    Vec3d p(u(rng), u(rng), u(rng));
    // Half the points close to the surface, where the sign is delicate.
    if (k % 2) p = p.normalized() * (0.2 + 0.02 * (u(rng) / 0.3));
    const double ref = bruteSignedDistance(s.mesh, p);
    maxExact = std::max(maxExact, std::abs(sdf.exactSignedDistance(p) - ref));
    if (!sdf.gridBox().contains(p.cast<Real>())) continue;
    const double grid = double(sdf.gridSignedDistance(p.cast<Real>()));
    (std::abs(ref) < 3 * h ? maxNear : maxFar) = std::max(std::abs(ref) < 3 * h ? maxNear : maxFar, std::abs(grid - ref));
    if (std::abs(ref) > h) signsAgree = signsAgree && (grid < 0) == (ref < 0);
  }
  EXPECT_LT(maxExact, 1e-9) << "BVH distance or pseudonormal sign differs from brute force";
  EXPECT_LT(maxNear, 0.5 * h);
  EXPECT_LT(maxFar, 3 * h);
  EXPECT_TRUE(signsAgree);
  EXPECT_LT(sdf.exactNodes(), sdf.nodes());
  if (verbose())
    std::printf("icosphere (320 triangles): exact error %.2e m, grid error within 3h of the surface %.4f h, farther %.3f h; "
                "%zu of %zu nodes exact\n",
                maxExact, maxNear / h, maxFar / h, sdf.exactNodes(), sdf.nodes());
}

TEST(MeshSdf, GridLargerThanTheCapIsRefused) {
  ObjSolid s = readObjSolid(testMeshes() + "/cube_quads.obj");
  try {
    MeshSdf sdf(s.mesh, {0.001, 0.005});  // 1 m cube at 1 mm: 1.02e9 nodes
    FAIL() << "accepted";
  } catch (const MeshGridTooLarge& e) {
    EXPECT_NE(std::string(e.what()).find("more than the limit"), std::string::npos) << e.what();
  }
}

// -------------------------------------------------------------- scenes ---

json meshScene(const std::string& file, const json& placement = json::object()) {
  json j = json::parse(R"({
    "dimension": 3,
    "particle_radius": 0.02,
    "domain": {"min": [0, 0, 0], "max": [1, 0.6, 0.4]},
    "fluid_blocks": [{"min": [0, 0, 0], "max": [0.2, 0.3, 0.4]}]
  })");
  json o = {{"type", "mesh"}, {"file", file}};
  o.update(placement);
  j["obstacles"] = json::array({o});
  return j;
}

template <int D = 3>
void expectSceneError(const json& scene, const std::string& path, const std::vector<std::string>& mentions) {
  try {
    parseScene<D>(scene);
    ADD_FAILURE() << "accepted: " << scene.dump();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, path) << e.what();
    for (const auto& m : mentions) EXPECT_NE(std::string(e.what()).find(m), std::string::npos) << "'" << m << "' missing in: " << e.what();
  }
}

TEST(MeshObstacleScene, PlacementAndSignedDistance) {
  // The unit cube scaled to 0.1 x 0.2 x 0.3, rotated 90° about z, centred at (0.6, 0.15, 0.2):
  // a box 0.2 wide in x, 0.1 in y, 0.3 in z.
  const SimulationSetup<3> s = parseScene<3>(meshScene(testMeshes() + "/cube_quads.obj",
                                                       {{"scale", {0.1, 0.2, 0.3}}, {"rotation", {0, 0, 90}},
                                                        {"translation", {0.6, 0.15, 0.2}}}));
  ASSERT_EQ(s.obstacles.size(), 1u);
  const Obstacle<3>& o = s.obstacles[0];
  EXPECT_EQ(o.shape, ObstacleShape::Mesh);
  EXPECT_NEAR(o.box.min[0], 0.5, 1e-6);
  EXPECT_NEAR(o.box.max[0], 0.7, 1e-6);
  EXPECT_NEAR(o.box.min[1], 0.1, 1e-6);
  EXPECT_NEAR(o.box.max[1], 0.2, 1e-6);
  EXPECT_NEAR(o.box.min[2], 0.05, 1e-6);
  EXPECT_NEAR(o.box.max[2], 0.35, 1e-6);
  EXPECT_NEAR(o.signedDistance(Vec3(0.6f, 0.15f, 0.2f)), -0.05, 1e-5);
  EXPECT_NEAR(o.signedDistance(Vec3(0.6f, 0.3f, 0.2f)), 0.1, 1e-5);
  // Near the surface the answer is exact, also beside a corner, where the
  // grid rounds (corner (0.7, 0.2, 0.35), 5 mm out along each axis).
  const Vec3 nearCorner(0.705f, 0.205f, 0.355f);
  EXPECT_NEAR(o.signedDistance(nearCorner), 0.005 * std::sqrt(3.0), 1e-6);
  EXPECT_GT(o.mesh->gridSignedDistance(nearCorner) - o.signedDistance(nearCorner), 0.001);
  const Obstacle<3> copy = o;  // cheap: the grid is shared
  EXPECT_EQ(copy.mesh.get(), o.mesh.get());
}

TEST(MeshObstacleScene, RoundTripKeepsTheMeshAndItsPlacement) {
  const json j = meshScene(testMeshes() + "/cube_quads.obj",
                           {{"scale", 0.1}, {"rotation", {10, 20, 30}}, {"translation", {0.6, 0.15, 0.2}}});
  const SimulationSetup<3> a = parseScene<3>(j);
  const json saved = sceneToJson(a);
  const json& o = saved["obstacles"][0];
  EXPECT_EQ(o["type"], "mesh");
  EXPECT_EQ(o["scale"], json({0.1, 0.1, 0.1}));
  EXPECT_EQ(o["rotation"], json({10, 20, 30}));
  const SimulationSetup<3> b = parseScene<3>(saved);
  EXPECT_EQ(b.obstacles[0].placement.file, a.obstacles[0].placement.file);
  EXPECT_EQ(b.obstacles[0].box.min, a.obstacles[0].box.min);
  EXPECT_EQ(b.obstacles[0].box.max, a.obstacles[0].box.max);
  EXPECT_EQ(sceneToJson(b), saved);
}

TEST(MeshObstacleScene, FilesAreResolvedFromTheSceneFilesDirectory) {
  const json j = loadSceneJson(badScenes() + "/mesh_open_box.json");
  const std::string file = j["obstacles"][1]["file"];
  EXPECT_TRUE(fs::path(file).is_absolute()) << file;
  EXPECT_TRUE(fs::exists(file)) << file;
  EXPECT_EQ(fs::path(file).filename(), "open_box.obj");
  // An inline scene reads the path as written (here: relative to a directory that has no such file).
  expectSceneError(meshScene("meshes/open_box.obj"), "obstacles[0].file", {"does not exist"});
}

TEST(MeshObstacleScene, BadMeshFilesAreSceneErrorsAtTheKeyPath) {
  auto load = [](const std::string& name) { return loadSceneJson(badScenes() + "/" + name); };
  expectSceneError(load("mesh_malformed.json"), "obstacles[1].file", {"malformed.obj:2:", "'zero' is not a number"});
  expectSceneError(load("mesh_index_out_of_range.json"), "obstacles[1].file",
                   {"index_out_of_range.obj:14:", "vertex index 9 is out of range"});
  expectSceneError(load("mesh_open_box.json"), "obstacles[1].file", {"not closed", "4 edges", "e.g. the edge from vertex"});
  expectSceneError(load("mesh_nonfinite.json"), "obstacles[1].file", {"nonfinite.obj:3:", "non-finite vertex coordinate 'nan'"});
  expectSceneError(load("mesh_missing.json"), "obstacles[1].file", {"does_not_exist.obj", "does not exist"});
  expectSceneError<2>(load("mesh_in_2d.json"), "obstacles[0].type", {"3D only"});
}

TEST(MeshObstacleScene, BadPlacementKeys) {
  const std::string cube = testMeshes() + "/cube_quads.obj";
  expectSceneError(meshScene(cube, {{"scale", 0}}), "obstacles[0].scale", {"must be > 0"});
  expectSceneError(meshScene(cube, {{"scale", {1, -1, 1}}}), "obstacles[0].scale[1]", {"must be > 0"});
  expectSceneError(meshScene(cube, {{"translation", {1, 2}}}), "obstacles[0].translation", {"3 components"});
  expectSceneError(meshScene(cube, {{"rotation", 30}}), "obstacles[0].rotation", {"Euler"});
  expectSceneError(meshScene(cube, {{"colour", 1}}), "obstacles[0].colour", {"unknown key"});
  expectSceneError(meshScene(testMeshes() + "/cube.stl"), "obstacles[0].file", {"not a Wavefront OBJ file"});
  json noFile = meshScene(cube);
  noFile["obstacles"][0].erase("file");
  expectSceneError(noFile, "obstacles[0].file", {"missing required key"});
  // A block overlapping the mesh solid.
  expectSceneError(meshScene(cube, {{"scale", 0.2}, {"translation", {0.15, 0.1, 0.2}}}), "fluid_blocks[0]",
                   {"inside obstacles[0]"});
  // The grid cap: a 100 m mesh at r = 0.02 m.
  json huge = meshScene(cube, {{"scale", 100}, {"translation", {0.5, -50, 0.2}}});
  expectSceneError(huge, "obstacles[0].file", {"signed-distance grid", "more than the limit"});
}

// ------------------------------------------------------------ sampling ---

// The boundary-volume sum Σ V_b W(x - x_b) at x: what the solid contributes to
// a fluid particle's density there (in units of the rest density).
double boundaryFill(const Simulation<3>& sim, const Vec3& x) {
  double sum = 0;
  for (size_t b = 0; b < sim.boundary.size(); ++b) sum += sim.boundary.volume[b] * sim.kernel.W(Vec3(x - sim.boundary.x[b]));
  return sum;
}

json tankWithObstacle(const json& obstacle) {
  json j = json::parse(R"({
    "dimension": 3,
    "particle_radius": 0.02,
    "domain": {"min": [0, 0, 0], "max": [1.2, 1.2, 1.2]},
    "fluid_blocks": [{"min": [0, 0, 0], "max": [0.08, 0.08, 0.08]}]
  })");
  j["obstacles"] = json::array({obstacle});
  return j;
}

TEST(MeshSampling, AxisAlignedBoxMeshIsSampledLikeTheBox) {
  // 0.32 x 0.24 x 0.4 m at r = 0.02: whole spacings, so both samplings are lattices.
  const Vec3d lo(0.4, 0.4, 0.4), size(0.32, 0.24, 0.4);
  const json mesh = {{"type", "mesh"}, {"file", testMeshes() + "/cube_quads.obj"},
                     {"scale", {size[0], size[1], size[2]}},
                     {"translation", {lo[0] + size[0] / 2, lo[1] + size[1] / 2, lo[2] + size[2] / 2}}};
  const json box = {{"type", "box"}, {"min", {lo[0], lo[1], lo[2]}}, {"max", {lo[0] + size[0], lo[1] + size[1], lo[2] + size[2]}}};
  const Simulation<3> a(parseScene<3>(tankWithObstacle(mesh)));
  const Simulation<3> b(parseScene<3>(tankWithObstacle(box)));
  EXPECT_EQ(a.boundary.size(), b.boundary.size());
  // Above the middle of the top face, one radius off it (a resting particle).
  const Vec3 probe(Real(lo[0] + size[0] / 2), Real(lo[1] + size[1] + 0.02), Real(lo[2] + size[2] / 2));
  EXPECT_NEAR(boundaryFill(a, probe), boundaryFill(b, probe), 1e-4);
}

// A plate one radius thick (thinner than the two radii a first layer needs):
// one lattice on its mid-plane, laid by one of its faces, so that a particle
// resting on it sees a solid: half a radius nearer than a thick box's first
// layer, so twice its density there (docs/physics/index.md, Mesh obstacles).
TEST(MeshSampling, ThinPlateIsSampledOnItsMidPlane) {
  const double r = 0.02, thickness = r;
  const Vec3d lo(0.4, 0.4, 0.4), size(0.4, thickness, 0.4);
  const json plate = {{"type", "mesh"}, {"file", testMeshes() + "/cube_quads.obj"},
                      {"scale", {size[0], size[1], size[2]}},
                      {"translation", {lo[0] + size[0] / 2, lo[1] + size[1] / 2, lo[2] + size[2] / 2}}};
  const json thick = {{"type", "box"}, {"min", {lo[0], lo[1] - 0.2, lo[2]}}, {"max", {lo[0] + size[0], lo[1] + thickness, lo[2] + size[2]}}};
  json walls = tankWithObstacle(plate);
  walls.erase("obstacles");
  const Simulation<3> a(parseScene<3>(tankWithObstacle(plate)));
  const Simulation<3> b(parseScene<3>(tankWithObstacle(thick)));
  const size_t wallSamples = Simulation<3>(parseScene<3>(walls)).boundary.size();
  ASSERT_GT(a.boundary.size(), wallSamples) << "the plate has no boundary samples";
  const double mid = lo[1] + thickness / 2;
  for (size_t i = wallSamples; i < a.boundary.size(); ++i)
    EXPECT_NEAR(double(a.boundary.x[i].y()), mid, 1e-5) << "sample " << i << " is off the plate's mid-plane";
  // One lattice of spacing 2r over the plate inset by r: 10 x 10 here.
  EXPECT_EQ(a.boundary.size() - wallSamples, 100u);
  const Vec3 probe(Real(lo[0] + size[0] / 2), Real(lo[1] + thickness + r), Real(lo[2] + size[2] / 2));
  const double thin = boundaryFill(a, probe), full = boundaryFill(b, probe);
  std::printf("thin plate: %zu samples, fill one radius above it %.4f (a thick box: %.4f)\n",
              a.boundary.size() - wallSamples, thin, full);
  EXPECT_GT(thin, 0.9 * full) << "a particle resting on the plate must see it as a solid";
  EXPECT_LT(thin, 2.5 * full);
}

TEST(MeshSampling, RotatedCubeFillsLikeTheAxisAlignedOne) {
  // A 0.3 m cube turned 30° about z and 20° about x: the samples are
  // projected, not a lattice; a particle resting on a face centre must see
  // about the same solid as on the axis-aligned cube.
  auto cube = [](const json& rotation) {
    return json{{"type", "mesh"}, {"file", testMeshes() + "/cube_quads.obj"}, {"scale", 0.3},
                {"translation", {0.6, 0.6, 0.6}}, {"rotation", rotation}};
  };
  const Simulation<3> straight(parseScene<3>(tankWithObstacle(cube({0, 0, 0}))));
  const Simulation<3> turned(parseScene<3>(tankWithObstacle(cube({20, 0, 30}))));
  const Eigen::Matrix3f R = (Eigen::AngleAxisf(20 * std::numbers::pi_v<float> / 180, Eigen::Vector3f::UnitX()) *
                             Eigen::AngleAxisf(30 * std::numbers::pi_v<float> / 180, Eigen::Vector3f::UnitZ()))
                                .toRotationMatrix();
  const Vec3 c(0.6f, 0.6f, 0.6f);
  double worst = 0;
  const double reference = boundaryFill(straight, Vec3(c + Vec3(0, 0.17f, 0)));
  for (int axis = 0; axis < 3; ++axis)
    for (int sign : {-1, 1}) {
      Vec3 n = Vec3::Zero();
      n[axis] = Real(sign);
      const double a = boundaryFill(straight, Vec3(c + Real(0.17) * n));
      const double b = boundaryFill(turned, Vec3(c + Real(0.17) * (R * n)));
      EXPECT_NEAR(a, reference, 1e-4);
      worst = std::max(worst, std::abs(b / a - 1));
    }
  EXPECT_LT(worst, 0.05) << "the turned cube's faces hold " << worst * 100 << " % more or less solid";
  const double samplesRatio = double(turned.boundary.size()) / double(straight.boundary.size());
  EXPECT_NEAR(samplesRatio, 1.0, 0.15);
  if (verbose())
    std::printf("turned cube: boundary fill off by at most %.2f %% on the face centres; %zu samples vs %zu\n", worst * 100,
                turned.boundary.size(), straight.boundary.size());
}

// ------------------------------------------------------------- physics ---

// A 3D dam break (r = 0.02 m, 360 particles) against a wall-like obstacle
// across the tank: x 0.40..0.51 m, height 0.13 m (not whole spacings), the
// full depth.
json damBreakAgainst(const json& obstacle) {
  json j = json::parse(R"({
    "dimension": 3,
    "particle_radius": 0.02,
    "domain": {"min": [0, 0, 0], "max": [0.8, 0.5, 0.24]},
    "fluid_blocks": [{"min": [0, 0, 0], "max": [0.24, 0.4, 0.24]}],
    "effects": [{"name": "viscosity_xsph", "coefficient": 0.05}]
  })");
  if (!obstacle.is_null()) j["obstacles"] = json::array({obstacle});
  return j;
}

const json kMeshWall = {{"type", "mesh"}, {"file", testMeshes() + "/cube_quads.obj"}, {"scale", {0.11, 0.13, 0.24}},
                        {"translation", {0.455, 0.065, 0.12}}};
const json kBoxWall = {{"type", "box"}, {"min", {0.4, 0, 0}}, {"max", {0.51, 0.13, 0.24}}};

struct DamBreakRun {
  std::vector<double> front;      // max x per frame
  std::vector<double> meanX;      // per frame
  std::vector<size_t> inShadow;   // particles in x 0.51..0.59, y < 0.06 per frame
  double minSignedDistance = 1e30;
  bool finite = true;
};

DamBreakRun runDamBreak(const json& obstacle, int frames) {
  Simulation<3> sim(parseScene<3>(damBreakAgainst(obstacle)));
  DamBreakRun r;
  for (int f = 0; f < frames; ++f) {
    const FrameStats fs = sim.advanceFrame();
    r.finite = r.finite && fs.finite;
    EXPECT_EQ(fs.escapedParticles, 0u) << "frame " << fs.frame;
    double front = 0, mean = 0;
    size_t shadow = 0;
    for (size_t i = 0; i < sim.fluid.size(); ++i) {
      const Vec3& x = sim.fluid.x[i];
      front = std::max(front, double(x[0]));
      mean += x[0];
      shadow += (x[0] > 0.51f && x[0] < 0.59f && x[1] < 0.06f) ? 1 : 0;
      for (const auto& o : sim.setup().obstacles) r.minSignedDistance = std::min(r.minSignedDistance, double(o.signedDistance(x)));
    }
    r.front.push_back(front);
    r.meanX.push_back(mean / double(sim.fluid.size()));
    r.inShadow.push_back(shadow);
  }
  return r;
}

TEST(MeshObstaclePhysics, DamBreakAgainstAMeshBoxIsDeflectedLikeTheAnalyticBox) {
  const int frames = 24;  // 0.4 s
  const DamBreakRun mesh = runDamBreak(kMeshWall, frames);
  const DamBreakRun box = runDamBreak(kBoxWall, frames);
  const DamBreakRun free = runDamBreak(json(), frames);
  EXPECT_TRUE(mesh.finite);
  EXPECT_TRUE(box.finite);
  EXPECT_GE(mesh.minSignedDistance, 0.0) << "a liquid particle ended a frame inside the mesh solid";
  EXPECT_GE(box.minSignedDistance, 0.0);
  double frontDiff = 0, meanDiff = 0;
  for (int f = 0; f < frames; ++f) {
    frontDiff = std::max(frontDiff, std::abs(mesh.front[size_t(f)] - box.front[size_t(f)]));
    meanDiff = std::max(meanDiff, std::abs(mesh.meanX[size_t(f)] - box.meanX[size_t(f)]));
    if (verbose())
      std::printf("frame %2d: front mesh %.3f box %.3f free %.3f | mean x mesh %.4f box %.4f | shadow mesh %zu box %zu free %zu\n",
                  f + 1, mesh.front[size_t(f)], box.front[size_t(f)], free.front[size_t(f)], mesh.meanX[size_t(f)],
                  box.meanX[size_t(f)], mesh.inShadow[size_t(f)], box.inShadow[size_t(f)], free.inShadow[size_t(f)]);
  }
  // The same solid, sampled the same way but for 4 of its deepest samples
  // (the box's sampler keeps a middle column in a part thinner than two
  // layers), with the same contact: the runs part only slowly.
  EXPECT_LT(meanDiff, 0.005) << "mean x of the liquid differs by more than r/4 between mesh and analytic box";
  EXPECT_LT(frontDiff, 0.05) << "the leading particle differs by more than 2.5 r between mesh and analytic box";
  // The first frames (up to 0.2 s): the free liquid runs through the shadow
  // region behind the wall, the deflected one does not reach it.
  size_t freeShadow = 0, meshShadow = 0, boxShadow = 0;
  for (int f = 0; f < 12; ++f) {
    freeShadow += free.inShadow[size_t(f)];
    meshShadow += mesh.inShadow[size_t(f)];
    boxShadow += box.inShadow[size_t(f)];
  }
  EXPECT_GT(freeShadow, 0u);
  EXPECT_EQ(meshShadow, 0u);
  EXPECT_EQ(boxShadow, 0u);
  if (verbose()) std::printf("largest front difference %.4f m, mean-x difference %.4f m\n", frontDiff, meanDiff);
}

}  // namespace
}  // namespace fc
