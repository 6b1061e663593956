#pragma once
// Wavefront OBJ files as closed solids (mesh obstacles, scenes/README.md).
// Read: `v x y z` (optionally `v x y z 1` or `v x y z r g b`), `f a b c ...`
// (polygons fan-triangulated; indices `a`, `a/t`, `a//n`, `a/t/n`; negative
// indices count back from the last vertex read), `#` comments, a trailing
// `\` continues a line. Ignored: vt, vn, vp, o, g, s, usemtl, mtllib. Any
// other statement is an error (lines, points and curves bound no solid).
// Vertices at exactly the same position are merged (exporters often split
// them at texture seams); vertices no face uses are dropped.
#include "core/mesh_sdf.h"
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

// What was wrong, naming the file ("FILE:LINE: ..." for a line, "FILE: ..."
// for the whole mesh).
struct MeshFileError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct ObjSolid {
  TriangleMesh mesh;               // closed, outward oriented, in file coordinates
  size_t polygons = 0;             // `f` statements
  size_t fileVertices = 0;         // `v` statements
  size_t mergedVertices = 0;       // duplicates of an earlier position
  bool flipped = false;            // the file's mesh was inside-out
};

// Reads `file` and checks it bounds a solid: at least 4 vertices and 4
// triangles, finite coordinates, indices in range, no degenerate triangle,
// every edge shared by exactly two faces running along it in opposite
// directions. A closed mesh with negative signed volume (inside-out) is
// flipped. Throws MeshFileError.
ObjSolid readObjSolid(const std::string& file);

}  // namespace fc
