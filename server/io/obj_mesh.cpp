#include "io/obj_mesh.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <unordered_map>

namespace fc {

namespace {

struct RawFace {
  std::vector<long> v;  // 1-based vertex indices, resolved (negative ones made absolute)
  size_t line = 0;
};

std::string num(double v) {
  std::ostringstream s;
  s.precision(9);
  s << v;
  return s.str();
}

std::string pos(const Vec3d& p) { return "(" + num(p[0]) + ", " + num(p[1]) + ", " + num(p[2]) + ")"; }

std::string shorten(const std::string& s) { return s.size() <= 40 ? s : s.substr(0, 37) + "..."; }

// 0: parsed; 1: not a number; 2: a number beyond the range of double.
int parseDouble(const std::string& s, double& out) {
  const char* b = s.data();
  const char* e = b + s.size();
  if (b != e && *b == '+') ++b;  // from_chars does not take a leading '+'
  const auto r = std::from_chars(b, e, out);
  if (r.ptr != e) return 1;
  return r.ec == std::errc() ? 0 : r.ec == std::errc::result_out_of_range ? 2 : 1;
}

bool parseLong(const std::string& s, long& out) {
  const char* b = s.data();
  const char* e = b + s.size();
  if (b != e && *b == '+') ++b;
  const auto r = std::from_chars(b, e, out);
  return r.ec == std::errc() && r.ptr == e;
}

}  // namespace

ObjSolid readObjSolid(const std::string& file) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(file, ec)) throw MeshFileError("mesh file '" + file + "' does not exist");
  if (fs::is_directory(file, ec)) throw MeshFileError("mesh file '" + file + "' is a directory");
  std::ifstream in(file, std::ios::binary);
  if (!in) throw MeshFileError("cannot open mesh file '" + file + "'");

  auto lineError = [&](size_t line, const std::string& what) -> MeshFileError {
    return MeshFileError(file + ":" + std::to_string(line) + ": " + what);
  };

  ObjSolid out;
  std::vector<Vec3d> verts;
  std::vector<size_t> vertLine;
  std::vector<RawFace> faces;
  std::string raw, text;
  size_t lineNo = 0, startLine = 0;
  bool continued = false;
  while (std::getline(in, raw)) {
    ++lineNo;
    if (!raw.empty() && raw.back() == '\r') raw.pop_back();
    if (!continued) text.clear(), startLine = lineNo;
    continued = !raw.empty() && raw.back() == '\\';
    if (continued) raw.pop_back();
    text += raw;
    if (continued) {
      text += ' ';
      continue;
    }
    const size_t hash = text.find('#');
    std::istringstream tokens(hash == std::string::npos ? text : text.substr(0, hash));
    std::string kw;
    if (!(tokens >> kw)) continue;
    std::vector<std::string> args;
    for (std::string a; tokens >> a;) args.push_back(a);
    const size_t line = startLine;
    if (kw == "v") {
      if (args.size() != 3 && args.size() != 4 && args.size() != 6)
        throw lineError(line, "a vertex needs 3 coordinates (optionally w = 1, or an RGB colour), got " +
                                  std::to_string(args.size()) + " numbers");
      double c[6];
      for (size_t k = 0; k < args.size(); ++k) {
        const int bad = parseDouble(args[k], c[k]);
        if (bad == 2) throw lineError(line, "non-finite vertex coordinate '" + shorten(args[k]) + "' (beyond the range of double)");
        if (bad) throw lineError(line, "'" + shorten(args[k]) + "' is not a number (vertex coordinate " + std::to_string(k + 1) + ")");
        if (!std::isfinite(c[k])) throw lineError(line, "non-finite vertex coordinate '" + shorten(args[k]) + "'");
      }
      if (args.size() == 4 && c[3] != 1) throw lineError(line, "vertex weight w = " + args[3] + " is not supported (only 1)");
      verts.emplace_back(c[0], c[1], c[2]);
      vertLine.push_back(line);
    } else if (kw == "f") {
      if (args.size() < 3) throw lineError(line, "a face needs at least 3 vertices, got " + std::to_string(args.size()));
      RawFace f;
      f.line = line;
      for (const std::string& a : args) {
        // "v", "v/t", "v//n" or "v/t/n": the position index first.
        std::vector<std::string> parts;
        size_t b = 0;
        for (size_t s; (s = a.find('/', b)) != std::string::npos; b = s + 1) parts.push_back(a.substr(b, s - b));
        parts.push_back(a.substr(b));
        long idx = 0;
        if (parts.size() > 3 || !parseLong(parts[0], idx))
          throw lineError(line, "'" + shorten(a) + "' is not a vertex reference (v, v/vt, v//vn or v/vt/vn)");
        for (size_t k = 1; k < parts.size(); ++k) {
          long ignored;
          if (!parts[k].empty() && !parseLong(parts[k], ignored))
            throw lineError(line, "'" + shorten(a) + "' is not a vertex reference (v, v/vt, v//vn or v/vt/vn)");
        }
        if (idx == 0) throw lineError(line, "vertex index 0: OBJ indices start at 1 (negative ones count back from the last vertex)");
        if (idx < 0) {
          const long abs = long(verts.size()) + idx + 1;
          if (abs < 1)
            throw lineError(line, "vertex index " + std::to_string(idx) + " is out of range: only " +
                                      std::to_string(verts.size()) + " vertices precede this line");
          idx = abs;
        }
        f.v.push_back(idx);
      }
      faces.push_back(std::move(f));
    } else if (kw == "vt" || kw == "vn" || kw == "vp" || kw == "o" || kw == "g" || kw == "s" || kw == "usemtl" ||
               kw == "mtllib") {
      continue;
    } else {
      throw lineError(line, "unsupported OBJ statement '" + shorten(kw) +
                                "' (a solid is read from v and f; vt, vn, vp, o, g, s, usemtl and mtllib are ignored)");
    }
  }
  if (in.bad()) throw MeshFileError("cannot read mesh file '" + file + "'");
  out.fileVertices = verts.size();
  out.polygons = faces.size();
  for (const RawFace& f : faces)
    for (long idx : f.v)
      if (idx > long(verts.size()))
        throw lineError(f.line, "vertex index " + std::to_string(idx) + " is out of range: the file has " +
                                    std::to_string(verts.size()) + " vertices");

  // Merge coincident positions (the first occurrence stands for all) and
  // number the vertices the faces use.
  std::map<std::array<double, 3>, uint32_t> byPosition;
  std::vector<uint32_t> canonical(verts.size());
  for (size_t i = 0; i < verts.size(); ++i) {
    const auto [it, fresh] = byPosition.try_emplace({verts[i][0], verts[i][1], verts[i][2]}, uint32_t(i));
    canonical[i] = it->second;
    if (!fresh) ++out.mergedVertices;
  }
  std::vector<uint32_t> compact(verts.size(), UINT32_MAX);
  std::vector<uint32_t> fileIndex;  // compact vertex -> 0-based index in the file
  std::vector<size_t> triLine;
  TriangleMesh& m = out.mesh;
  auto use = [&](long idx) {
    const uint32_t c = canonical[size_t(idx - 1)];
    if (compact[c] == UINT32_MAX) {
      compact[c] = uint32_t(m.vertices.size());
      m.vertices.push_back(verts[c]);
      fileIndex.push_back(c);
    }
    return compact[c];
  };
  for (const RawFace& f : faces)
    for (size_t k = 1; k + 1 < f.v.size(); ++k) {
      m.triangles.push_back({use(f.v[0]), use(f.v[k]), use(f.v[k + 1])});
      triLine.push_back(f.line);
    }
  if (m.vertices.size() < 4 || m.triangles.size() < 4)
    throw MeshFileError(file + ": a closed solid needs at least 4 vertices and 4 triangles; the faces use " +
                        std::to_string(m.vertices.size()) + " vertices in " + std::to_string(m.triangles.size()) +
                        " triangles");

  auto vname = [&](uint32_t v) { return "vertex " + std::to_string(fileIndex[v] + 1) + " " + pos(m.vertices[v]); };

  // Degenerate triangles (relative to the mesh size).
  const AABB<3> box = m.bounds();
  const double diag = box.size().cast<double>().norm();
  for (size_t t = 0; t < m.triangles.size(); ++t) {
    const auto& v = m.triangles[t];
    const double area2 = (m.vertices[v[1]] - m.vertices[v[0]]).cross(m.vertices[v[2]] - m.vertices[v[0]]).norm();
    if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0] || !(area2 > 1e-12 * diag * diag))
      throw lineError(triLine[t], "degenerate triangle: " + vname(v[0]) + ", " + vname(v[1]) + " and " + vname(v[2]) +
                                      " are collinear or coincide (zero area)");
  }

  // Closed and consistently oriented: every directed edge a->b once, and b->a
  // once, in another face.
  std::unordered_map<uint64_t, std::vector<uint32_t>> directed;
  directed.reserve(3 * m.triangles.size());
  auto edgeKey = [](uint32_t a, uint32_t b) { return (uint64_t(a) << 32) | b; };
  for (uint32_t t = 0; t < m.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k) directed[edgeKey(m.triangles[t][size_t(k)], m.triangles[t][size_t((k + 1) % 3)])].push_back(t);
  size_t openEdges = 0, crowdedEdges = 0, flippedEdges = 0;
  std::string openExample, crowdedExample, flippedExample;
  // Examples from the first edges in file order (the map's order is not).
  std::vector<std::pair<uint64_t, const std::vector<uint32_t>*>> edges;
  edges.reserve(directed.size());
  for (const auto& [k, ts] : directed) edges.emplace_back(k, &ts);
  std::sort(edges.begin(), edges.end(), [](const auto& x, const auto& y) {
    return std::make_pair(x.second->front(), x.first) < std::make_pair(y.second->front(), y.first);
  });
  for (const auto& [k, tsp] : edges) {
    const std::vector<uint32_t>& ts = *tsp;
    const uint32_t a = uint32_t(k >> 32), b = uint32_t(k & 0xffffffffu);
    const auto rev = directed.find(edgeKey(b, a));
    const size_t n = ts.size() + (rev == directed.end() ? 0 : rev->second.size());
    if (rev != directed.end() && a > b) continue;  // count each undirected edge once
    if (n == 1) {
      if (openEdges++ == 0)
        openExample = "the edge from " + vname(a) + " to " + vname(b) + " of the face at line " +
                      std::to_string(triLine[ts[0]]) + " has no other face";
    } else if (n > 2) {
      if (crowdedEdges++ == 0)
        crowdedExample = "the edge between " + vname(a) + " and " + vname(b) + " is shared by " + std::to_string(n) +
                         " faces (lines " + std::to_string(triLine[ts[0]]) + ", " +
                         std::to_string(triLine[ts.size() > 1 ? ts[1] : rev->second[0]]) + ", ...)";
    } else if (ts.size() == 2) {
      if (flippedEdges++ == 0)
        flippedExample = "the faces at lines " + std::to_string(triLine[ts[0]]) + " and " + std::to_string(triLine[ts[1]]) +
                         " both run from " + vname(a) + " to " + vname(b);
    }
  }
  if (openEdges)
    throw MeshFileError(file + ": the mesh is not closed: " + std::to_string(openEdges) +
                        (openEdges == 1 ? " edge belongs" : " edges belong") + " to one face only, e.g. " + openExample +
                        " (every edge must be shared by exactly two faces)");
  if (crowdedEdges)
    throw MeshFileError(file + ": the mesh is not a closed surface: " + std::to_string(crowdedEdges) +
                        (crowdedEdges == 1 ? " edge is" : " edges are") + " shared by more than two faces, e.g. " +
                        crowdedExample);
  if (flippedEdges)
    throw MeshFileError(file + ": the faces are not consistently oriented: " + std::to_string(flippedEdges) +
                        (flippedEdges == 1 ? " edge is" : " edges are") + " traversed in the same direction by both of its faces, e.g. " +
                        flippedExample + " (neighbouring faces must list their shared edge in opposite orders; flip one)");

  const double volume = m.signedVolume();
  if (!(std::abs(volume) > 1e-12 * diag * diag * diag))
    throw MeshFileError(file + ": the closed mesh encloses no volume (" + num(volume) + ")");
  if (volume < 0) {
    m.flip();
    out.flipped = true;
  }
  return out;
}

}  // namespace fc
