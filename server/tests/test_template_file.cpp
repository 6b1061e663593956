// Template file format (io/template_file.h): round trip within the documented
// quantization bounds, size on disk, atomic write, and every bad-input case.
#include "io/template_file.h"
#include "tests/hdf5_test_util.h"

#include <gtest/gtest.h>
#include <algorithm>
#include <limits>
#include <type_traits>
#include <hdf5.h>
#include <nlohmann/json.hpp>
#include <zlib.h>

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using namespace fc;
using fc::test::readFile;
using fc::test::TempDir;

namespace {

struct BlobSpec {
  int nx = 8, ny = 6, nz = 8;  // lattice particles per axis (nz unused in 2D)
  int frames = 30;
  int emptyFrame = 7;          // -1: none
  double radius = 0.01;
  double regionSize = 1.0;     // region [0, regionSize]^D
  unsigned seed = 1;
};

// A liquid-like template: a lattice blob (spacing 2r) of two phases resting
// on y = 0.1, sloshing (shear + travelling surface wave) over the frames.
// Positions carry a fixed per-particle jitter (0.1 r, as relaxed SPH
// particles) plus a small per-frame jitter (0.02 r); velocities are the
// analytic motion plus 1 % noise. The capture box is a moving cut in x, so
// the particle count varies; one frame is empty.
template <int D>
Template<D> makeBlob(const BlobSpec& s) {
  Template<D> t;
  TemplateHeader& h = t.header;
  h.name = "blob_" + std::to_string(D) + "d";
  h.dimension = D;
  h.frameRate = 60;
  h.particleRadius = s.radius;
  h.supportRadius = 4 * s.radius;
  h.restDensity = 1000;
  h.regionMin.assign(D, 0.0);
  h.regionMax.assign(D, s.regionSize);
  h.recipe = R"({"dimension": )" + std::to_string(D) + R"(, "name": "blob", "note": "synthetic test data"})";
  h.createdBy = "flowclip tests";

  const double r = s.radius, dx = 2 * r;
  const int nz = D == 3 ? s.nz : 1;
  const double m0 = 1000 * std::pow(dx, D), m1 = 0.8 * m0;
  std::mt19937 rng(s.seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<Vec<D>> base;
  std::vector<uint8_t> ph;
  const double x0 = 0.5 * s.regionSize - 0.5 * s.nx * dx, y0 = 0.1, z0 = 0.5 * s.regionSize - 0.5 * nz * dx;
  const double H = s.ny * dx, W = s.nx * dx;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < s.ny; ++j)
      for (int i = 0; i < s.nx; ++i) {
        Vec<D> p;
        p[0] = Real(x0 + (i + 0.5) * dx + 0.1 * r * u(rng));
        p[1] = Real(y0 + (j + 0.5) * dx + 0.1 * r * u(rng));
        if constexpr (D == 3) p[2] = Real(z0 + (k + 0.5) * dx + 0.1 * r * u(rng));
        base.push_back(p);
        ph.push_back(j >= 2 * s.ny / 3 ? 1 : 0);
      }
  const double w = 2 * M_PI * 1.5;  // 1.5 Hz sloshing
  for (int f = 0; f < s.frames; ++f) {
    const double time = f / h.frameRate;
    TemplateFrame<D> fr;
    const double cut = x0 + W * (0.75 + 0.25 * std::sin(0.3 * f));  // captured: x < cut
    if (f != s.emptyFrame) {
      for (size_t p = 0; p < base.size(); ++p) {
        const double hgt = (base[p][1] - y0) / H;  // 0..1
        const double kx = 2 * M_PI * (base[p][0] - x0) / W;
        Vec<D> x = base[p], v = Vec<D>::Zero();
        x[0] += Real(0.3 * H * hgt * std::sin(w * time));
        v[0] += Real(0.3 * H * hgt * w * std::cos(w * time));
        x[1] += Real(0.15 * H * hgt * std::sin(kx - w * time));
        v[1] += Real(-0.15 * H * hgt * w * std::cos(kx - w * time));
        if constexpr (D == 3) {
          x[2] += Real(0.05 * H * hgt * std::sin(w * time + 1));
          v[2] += Real(0.05 * H * hgt * w * std::cos(w * time + 1));
        }
        const double speed = v.norm();
        for (int d = 0; d < D; ++d) {
          x[d] += Real(0.02 * r * u(rng));
          v[d] += Real(0.01 * (speed + 0.05) * u(rng));
        }
        if (x[0] >= cut) continue;
        fr.x.push_back(x);
        fr.v.push_back(v);
        fr.mass.push_back(Real(ph[p] ? m1 : m0));
        fr.phase.push_back(ph[p]);
      }
    }
    t.frames.push_back(std::move(fr));
  }
  return t;
}

void expectHeaderEqual(const TemplateHeader& a, const TemplateHeader& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.dimension, b.dimension);
  EXPECT_EQ(a.frameRate, b.frameRate);
  EXPECT_EQ(a.particleRadius, b.particleRadius);
  EXPECT_EQ(a.supportRadius, b.supportRadius);
  EXPECT_EQ(a.restDensity, b.restDensity);
  EXPECT_EQ(a.regionMin, b.regionMin);
  EXPECT_EQ(a.regionMax, b.regionMax);
  EXPECT_EQ(a.recipe, b.recipe);
  EXPECT_EQ(a.createdBy, b.createdBy);
}

// Every particle of every frame of `out` equals one of `in` (a bijection;
// the file's particle order within a frame is its own) within the documented
// bounds: positions 0.01 r per axis, velocities max|v| / 2046 per component,
// masses and phases exact.
template <int D>
void expectFramesMatch(const Template<D>& in, const Template<D>& out, double posBound) {
  ASSERT_EQ(in.frameCount(), out.frameCount());
  for (size_t f = 0; f < in.frameCount(); ++f) {
    const auto& a = in.frames[f];
    const auto& b = out.frames[f];
    ASSERT_EQ(a.size(), b.size()) << "frame " << f;
    ASSERT_EQ(b.v.size(), b.size());
    ASSERT_EQ(b.mass.size(), b.size());
    ASSERT_EQ(b.phase.size(), b.size());
    double vmax = 0;
    for (auto& v : a.v) vmax = std::max(vmax, double(v.cwiseAbs().maxCoeff()));
    // scale / 2 with scale = vmax / 1023, plus float rounding of the decoded value.
    const double velBound = vmax / 2046 + vmax * (sizeof(Real) == 4 ? 1.2e-7 : 1e-15);
    std::vector<bool> used(a.size(), false);
    for (size_t k = 0; k < b.size(); ++k) {
      size_t best = 0;
      double bestD = 1e300;
      for (size_t i = 0; i < a.size(); ++i) {
        const double d = double((a.x[i] - b.x[k]).squaredNorm());
        if (d < bestD) bestD = d, best = i;
      }
      ASSERT_FALSE(used[best]) << "frame " << f << ": two stored particles match input particle " << best;
      used[best] = true;
      for (int d = 0; d < D; ++d) {
        ASSERT_LE(std::abs(double(a.x[best][d]) - double(b.x[k][d])), posBound) << "frame " << f << " axis " << d;
        ASSERT_LE(std::abs(double(a.v[best][d]) - double(b.v[k][d])), velBound) << "frame " << f << " axis " << d;
      }
      ASSERT_EQ(a.mass[best], b.mass[k]) << "frame " << f;
      ASSERT_EQ(a.phase[best], b.phase[k]) << "frame " << f;
    }
  }
}

// --- raw HDF5 edits used to build bad files --------------------------------

// Rewrites the checksum block (templates/README.md: the first 512 bytes,
// CRC-32 and length of the rest) after an edit through HDF5, so that the
// reader gets past it to the check under test.
void restampChecksum(const std::string& path) {
  std::string data = readFile(path);
  ASSERT_GT(data.size(), 512u);
  ASSERT_EQ(data.compare(0, 18, "FLOWCLIP TEMPLATE\n"), 0) << path;
  const uLong crc = crc32_z(0, reinterpret_cast<const Bytef*>(data.data() + 512), data.size() - 512);
  char text[96];
  std::snprintf(text, sizeof text, "FLOWCLIP TEMPLATE\ncrc32 %08lx\nlength %zu\n", crc, data.size() - 512);
  std::string block(text);
  block.resize(512, '\0');
  data.replace(0, 512, block);
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(data.data(), std::streamsize(data.size()));
}

std::string stringAttr(const std::string& path, const char* name) {
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  hid_t a = H5Aopen(f, name, H5P_DEFAULT);
  hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, H5T_VARIABLE);
  H5Tset_cset(t, H5T_CSET_UTF8);
  char* p = nullptr;
  H5Aread(a, t, &p);
  std::string s = p ? p : "";
  free(p);
  H5Tclose(t);
  H5Aclose(a);
  H5Fclose(f);
  return s;
}

template <class T>
void setAttr(const std::string& path, const char* name, hid_t type, T value) {
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  if (H5Aexists(f, name) > 0) H5Adelete(f, name);
  hid_t s = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(f, name, type, s, H5P_DEFAULT, H5P_DEFAULT);
  ASSERT_GE(H5Awrite(a, type, &value), 0);
  H5Aclose(a);
  H5Sclose(s);
  H5Fclose(f);
  restampChecksum(path);
}

void deleteAttr(const std::string& path, const char* name) {
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  ASSERT_GE(H5Adelete(f, name), 0);
  H5Fclose(f);
  restampChecksum(path);
}

// Overwrites element `index` of a one-dimensional dataset.
template <class T>
void setElement(const std::string& path, const char* dataset, hid_t memType, hsize_t index, T value) {
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  hid_t d = H5Dopen2(f, dataset, H5P_DEFAULT);
  ASSERT_GE(d, 0);
  hid_t fs = H5Dget_space(d);
  const hsize_t one = 1;
  H5Sselect_hyperslab(fs, H5S_SELECT_SET, &index, nullptr, &one, nullptr);
  hid_t ms = H5Screate_simple(1, &one, nullptr);
  ASSERT_GE(H5Dwrite(d, memType, ms, fs, H5P_DEFAULT, &value), 0);
  H5Sclose(ms);
  H5Sclose(fs);
  H5Dclose(d);
  H5Fclose(f);
  restampChecksum(path);
}

// Expects readTemplate<D> (and, if `header`, readTemplateHeader) to throw a
// TemplateError naming the file and containing `text`.
template <int D>
void expectBad(const std::string& path, const std::string& text, bool header = true) {
  try {
    readTemplate<D>(path);
    ADD_FAILURE() << "readTemplate<" << D << "> accepted " << path << " (expected: " << text << ")";
  } catch (const TemplateError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(path), std::string::npos) << msg;
    EXPECT_NE(msg.find(text), std::string::npos) << "message: " << msg << "\nexpected to contain: " << text;
  }
  if (header) {
    EXPECT_THROW(readTemplateHeader(path), TemplateError);
  }
}

}  // namespace

// --- round trips --------------------------------------------------------------

TEST(TemplateFile, RoundTrip3D) {
  TempDir dir;
  const auto in = makeBlob<3>(BlobSpec{});
  const std::string path = dir.file("blob.h5");
  writeTemplate(path, in);
  EXPECT_EQ(stringAttr(path, "position_encoding"), "uint16");
  EXPECT_EQ(stringAttr(path, "mass_encoding"), "table");
  const auto out = readTemplate<3>(path);
  expectHeaderEqual(in.header, out.header);
  expectHeaderEqual(in.header, readTemplateHeader(path));
  EXPECT_EQ(out.frames[7].size(), 0u);
  expectFramesMatch(in, out, 0.01 * in.header.particleRadius);
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"blob.h5"});  // no temporary left
}

TEST(TemplateFile, RoundTrip2D) {
  TempDir dir;
  BlobSpec s;
  s.nx = 20, s.ny = 15;
  const auto in = makeBlob<2>(s);
  const std::string path = dir.file("blob.h5");
  writeTemplate(path, in);
  EXPECT_EQ(stringAttr(path, "position_encoding"), "uint16");
  const auto out = readTemplate<2>(path);
  expectHeaderEqual(in.header, out.header);
  expectFramesMatch(in, out, 0.01 * in.header.particleRadius);
}

TEST(TemplateFile, LargeRegionFallsBackToFloat32Positions) {
  TempDir dir;
  BlobSpec s;
  s.regionSize = 100;  // 100 m / 65535 steps > 2 % of r = 0.01 m
  const auto in = makeBlob<3>(s);
  const std::string path = dir.file("big.h5");
  writeTemplate(path, in);
  EXPECT_EQ(stringAttr(path, "position_encoding"), "float32");
  const auto out = readTemplate<3>(path);
  expectFramesMatch(in, out, sizeof(Real) == 4 ? 0.0 : 1e-5);
}

TEST(TemplateFile, ManyDistinctMassesAreStoredPerParticle) {
  TempDir dir;
  BlobSpec s;
  s.nx = 20, s.ny = 15, s.emptyFrame = -1;
  auto in = makeBlob<2>(s);
  for (auto& fr : in.frames)
    for (size_t i = 0; i < fr.size(); ++i) fr.mass[i] *= Real(1 + 1e-3 * double(i));
  const std::string path = dir.file("masses.h5");
  writeTemplate(path, in);
  EXPECT_EQ(stringAttr(path, "mass_encoding"), "float64");
  expectFramesMatch(in, readTemplate<2>(path), 0.01 * in.header.particleRadius);
}

TEST(TemplateFile, TemplateWithoutFrames) {
  TempDir dir;
  BlobSpec s;
  s.frames = 0;
  const auto in = makeBlob<3>(s);
  const std::string path = dir.file("empty.h5");
  writeTemplate(path, in);
  const auto out = readTemplate<3>(path);
  expectHeaderEqual(in.header, out.header);
  EXPECT_EQ(out.frameCount(), 0u);
  const auto st = templateFileStats(path);
  EXPECT_EQ(st.frames, 0u);
  EXPECT_EQ(st.bytesPerParticleFrame, 0.0);
}

// --- size on disk -------------------------------------------------------------

// Realistic sizes: thousands of particles per frame (HDF5's fixed overhead of
// a few KB is then negligible, as in a recorded template).
template <int D>
TemplateFileStats measure(const BlobSpec& s, const std::string& path) {
  const auto in = makeBlob<D>(s);
  size_t rows = 0;
  for (auto& f : in.frames) rows += f.size();
  const auto t0 = std::chrono::steady_clock::now();
  writeTemplate(path, in);
  const auto t1 = std::chrono::steady_clock::now();
  const auto out = readTemplate<D>(path);
  const auto t2 = std::chrono::steady_clock::now();
  const auto st = templateFileStats(path);
  if (const char* keep = std::getenv("FLOWCLIP_TEMPLATE_SAMPLE_DIR"))
    fs::copy_file(path, fs::path(keep) / fs::path(path).filename(), fs::copy_options::overwrite_existing);
  auto mps = [&](auto a, auto b) { return double(rows) / std::chrono::duration<double>(b - a).count() / 1e6; };
  std::printf("[ %dD ] %zu frames, %zu..%zu particles (avg %.0f), %llu bytes, %.3f bytes/particle-frame "
              "(raw float32: %d); write %.1f M particle-frames/s, read %.1f M/s\n",
              D, st.frames, st.minParticles, st.maxParticles, st.avgParticles,
              (unsigned long long)st.bytesOnDisk, st.bytesPerParticleFrame, D == 3 ? 28 : 20, mps(t0, t1),
              mps(t1, t2));
  EXPECT_EQ(st.frames, size_t(s.frames));
  EXPECT_EQ(st.minParticles, 0u);  // the empty frame
  EXPECT_EQ(double(rows) / s.frames, st.avgParticles);
  EXPECT_EQ(out.frameCount(), size_t(s.frames));
  return st;
}

TEST(TemplateFile, SizeTarget3D) {
  TempDir dir;
  BlobSpec s;
  s.nx = 20, s.ny = 12, s.nz = 20, s.frames = 60;  // 4800 particles per full frame
  const auto st = measure<3>(s, dir.file("size3d.h5"));
  EXPECT_LT(st.bytesPerParticleFrame, 7.0);
}

TEST(TemplateFile, SizeTarget2D) {
  TempDir dir;
  BlobSpec s;
  s.nx = 60, s.ny = 30, s.frames = 60;  // 1800 particles per full frame
  const auto st = measure<2>(s, dir.file("size2d.h5"));
  EXPECT_LT(st.bytesPerParticleFrame, 5.0);
}

// --- atomic write -------------------------------------------------------------

TEST(TemplateFile, FailedWriteLeavesExistingFileUntouched) {
  TempDir dir;
  const auto good = makeBlob<3>(BlobSpec{});
  const std::string path = dir.file("t.h5");
  writeTemplate(path, good);
  const std::string before = readFile(path);

  // Into a missing directory: nothing created anywhere.
  EXPECT_THROW(writeTemplate(dir.file("missing/t.h5"), good), TemplateError);
  EXPECT_FALSE(fs::exists(dir.file("missing")));

  // Invalid content for an existing name: the old file stays, no temporary.
  auto bad = good;
  bad.frames[3].v[5][1] = std::numeric_limits<Real>::quiet_NaN();
  try {
    writeTemplate(path, bad);
    ADD_FAILURE() << "a NaN velocity was written";
  } catch (const TemplateError& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("non-finite"), std::string::npos) << e.what();
  }
  auto wrongDim = good;
  wrongDim.header.dimension = 2;
  EXPECT_THROW(writeTemplate(path, wrongDim), TemplateError);
  auto badName = good;
  badName.header.name = "../escape";
  EXPECT_THROW(writeTemplate(path, badName), TemplateError);
  EXPECT_EQ(readFile(path), before);
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"t.h5"});

  // A read-only directory: creating the temporary fails, old file intact.
  if (::geteuid() != 0) {
    fs::permissions(dir.file(""), fs::perms::owner_read | fs::perms::owner_exec);
    EXPECT_THROW(writeTemplate(path, good), TemplateError);
    fs::permissions(dir.file(""), fs::perms::owner_all);
    EXPECT_EQ(readFile(path), before);
    EXPECT_EQ(dir.entries(), std::vector<std::string>{"t.h5"});
  }

  // A successful write replaces the file.
  auto other = good;
  other.header.name = "other";
  writeTemplate(path, other);
  EXPECT_EQ(readTemplateHeader(path).name, "other");
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"t.h5"});
}

// --- bad input ------------------------------------------------------------------

class TemplateFileBad : public ::testing::Test {
 protected:
  void SetUp() override {
    BlobSpec s;
    s.nx = 5, s.ny = 4, s.nz = 3, s.frames = 6, s.emptyFrame = 2;
    writeTemplate(path2 = dir.file("two.h5"), makeBlob<2>(s));
    writeTemplate(path3 = dir.file("three.h5"), makeBlob<3>(s));
  }
  std::string copy(const std::string& name) {
    const std::string p = dir.file(name);
    fs::copy_file(path3, p);
    return p;
  }
  TempDir dir;
  std::string path2, path3;
};

TEST_F(TemplateFileBad, MissingFile) { expectBad<3>(dir.file("nope.h5"), "does not exist"); }

TEST_F(TemplateFileBad, NotHdf5) {
  const std::string p = dir.file("text.h5");
  std::ofstream(p) << "{\"this\": \"is json\"}\n";
  expectBad<3>(p, "not an HDF5 file");
  const std::string empty = dir.file("empty.h5");
  std::ofstream(empty).flush();
  expectBad<3>(empty, "not an HDF5 file");
}

TEST_F(TemplateFileBad, TruncatedFile) {
  const std::string data = readFile(path3);
  for (double frac : {0.5, 0.9}) {
    const std::string p = dir.file("cut" + std::to_string(int(frac * 100)) + ".h5");
    std::ofstream(p, std::ios::binary).write(data.data(), std::streamsize(data.size() * frac));
    expectBad<3>(p, "is truncated or damaged");
  }
}

TEST_F(TemplateFileBad, CorruptChunks) {
  // Overwrite the middle of the file (compressed particle chunks) with junk.
  const std::string p = copy("junk.h5");
  std::string data = readFile(p);
  for (size_t i = data.size() / 2; i < data.size() / 2 + 512 && i < data.size(); ++i) data[i] = char(0xA5);
  std::ofstream(p, std::ios::binary | std::ios::trunc).write(data.data(), std::streamsize(data.size()));
  try {
    readTemplate<3>(p);
    // Junk that happens to land in padding could still decode: acceptable
    // only if nothing is thrown other than TemplateError.
  } catch (const TemplateError& e) {
    EXPECT_NE(std::string(e.what()).find(p), std::string::npos);
  }
}

TEST_F(TemplateFileBad, Hdf5ButNotATemplate) {
  const std::string p = dir.file("other.h5");
  hid_t f = H5Fcreate(p.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  hid_t g = H5Gcreate2(f, "particles", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  H5Gclose(g);
  H5Fclose(f);
  expectBad<3>(p, "is HDF5 but not a FlowClip template, or is damaged (HDF5 superblock version 0");

  // The HDF5 1.10 format, as templates use, without the attribute.
  const std::string p110 = dir.file("other110.h5");
  hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
  H5Pset_libver_bounds(fapl, H5F_LIBVER_V110, H5F_LIBVER_V110);
  f = H5Fcreate(p110.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl);
  H5Pclose(fapl);
  ASSERT_GE(f, 0);
  H5Fclose(f);
  expectBad<3>(p110, "not a FlowClip template (no 'format' attribute)");

  const std::string q = copy("frames.h5");  // another flowclip format
  hid_t fq = H5Fopen(q.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  H5Adelete(fq, "format");
  hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, H5T_VARIABLE);
  hid_t s = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(fq, "format", t, s, H5P_DEFAULT, H5P_DEFAULT);
  const char* v = "flowclip-frames";
  H5Awrite(a, t, &v);
  H5Aclose(a), H5Sclose(s), H5Tclose(t), H5Fclose(fq);
  restampChecksum(q);
  expectBad<3>(q, "format is 'flowclip-frames'");
}

TEST_F(TemplateFileBad, WrongFormatVersion) {
  const std::string p = copy("v2.h5");
  setAttr(p, "format_version", H5T_NATIVE_INT, 2);
  expectBad<3>(p, "format_version 2");
  const std::string q = copy("nov.h5");
  deleteAttr(q, "format_version");
  expectBad<3>(q, "no 'format_version' attribute");
}

TEST_F(TemplateFileBad, DimensionMismatch) {
  expectBad<3>(path2, "is a 2D template, expected a 3D one", false);
  expectBad<2>(path3, "is a 3D template, expected a 2D one", false);
  EXPECT_EQ(readTemplateHeader(path2).dimension, 2);
  const std::string p = copy("dim4.h5");
  setAttr(p, "dimension", H5T_NATIVE_INT, 4);
  expectBad<3>(p, "dimension 4");
}

TEST_F(TemplateFileBad, InconsistentOffsets) {
  const std::string end = copy("end.h5");
  setElement<uint64_t>(end, "/frames/offset", H5T_NATIVE_UINT64, 6, 1000000);
  expectBad<3>(end, "/frames/offset ends at 1000000", false);
  EXPECT_THROW(templateFileStats(end), TemplateError);

  const std::string dec = copy("dec.h5");
  setElement<uint64_t>(dec, "/frames/offset", H5T_NATIVE_UINT64, 4, 1);
  expectBad<3>(dec, "/frames/offset decreases", false);

  const std::string cnt = copy("count.h5");
  setAttr(cnt, "frame_count", H5T_NATIVE_INT64, int64_t(9));
  expectBad<3>(cnt, "expected frame_count + 1", false);
}

TEST_F(TemplateFileBad, NonFiniteValues) {
  const std::string r = copy("radius.h5");
  setAttr(r, "particle_radius", H5T_NATIVE_DOUBLE, std::nan(""));
  expectBad<3>(r, "'particle_radius' is not finite");

  const std::string sc = copy("scale.h5");
  setElement<double>(sc, "/frames/velocity_scale", H5T_NATIVE_DOUBLE, 1, std::numeric_limits<double>::infinity());
  expectBad<3>(sc, "velocity_scale of frame 1 is negative or not finite", false);

  // float32 positions (large region) with a NaN.
  BlobSpec s;
  s.nx = 5, s.ny = 4, s.nz = 3, s.frames = 3, s.emptyFrame = -1, s.regionSize = 100;
  const std::string fp = dir.file("float.h5");
  writeTemplate(fp, makeBlob<3>(s));
  ASSERT_EQ(stringAttr(fp, "position_encoding"), "float32");
  {
    hid_t f = H5Fopen(fp.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    hid_t d = H5Dopen2(f, "/particles/position", H5P_DEFAULT);
    hid_t fs = H5Dget_space(d);
    const hsize_t start[2] = {3, 1}, count[2] = {1, 1};
    H5Sselect_hyperslab(fs, H5S_SELECT_SET, start, nullptr, count, nullptr);
    hid_t ms = H5Screate_simple(2, count, nullptr);
    const float nan = std::nanf("");
    ASSERT_GE(H5Dwrite(d, H5T_NATIVE_FLOAT, ms, fs, H5P_DEFAULT, &nan), 0);
    H5Sclose(ms), H5Sclose(fs), H5Dclose(d), H5Fclose(f);
  }
  restampChecksum(fp);
  expectBad<3>(fp, "/particles/position row 3 is not finite", false);
}

TEST_F(TemplateFileBad, MissingDatasetAndBadMassIndex) {
  const std::string m = copy("mass.h5");
  setElement<uint8_t>(m, "/particles/mass_index", H5T_NATIVE_UINT8, 0, 200);
  expectBad<3>(m, "/particles/mass_index row 0 is outside mass_table", false);

  const std::string v = copy("novel.h5");
  hid_t f = H5Fopen(v.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  H5Ldelete(f, "/particles/velocity", H5P_DEFAULT);
  H5Fclose(f);
  restampChecksum(v);
  expectBad<3>(v, "has no dataset /particles/velocity", false);
}

// Replaces /particles/phase by a dataset of the same rows made with `dcpl`.
void replacePhase(const std::string& path, hid_t dcpl) {
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  hid_t d = H5Dopen2(f, "/particles/phase", H5P_DEFAULT);
  hid_t old = H5Dget_space(d);
  hsize_t rows = 0;
  H5Sget_simple_extent_dims(old, &rows, nullptr);
  H5Sclose(old);
  std::vector<uint8_t> phase(rows);
  H5Dread(d, H5T_NATIVE_UINT8, H5S_ALL, H5S_ALL, H5P_DEFAULT, phase.data());
  H5Dclose(d);
  H5Ldelete(f, "/particles/phase", H5P_DEFAULT);
  hid_t space = H5Screate_simple(1, &rows, nullptr);
  d = H5Dcreate2(f, "/particles/phase", H5T_STD_U8LE, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
  ASSERT_GE(d, 0);
  ASSERT_GE(H5Dwrite(d, H5T_NATIVE_UINT8, H5S_ALL, H5S_ALL, H5P_DEFAULT, phase.data()), 0);
  H5Dclose(d);
  H5Sclose(space);
  H5Fclose(f);
  restampChecksum(path);
}

void setString(const std::string& path, const char* name, const std::string& value) {
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  H5Adelete(f, name);
  hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, H5T_VARIABLE);
  H5Tset_cset(t, H5T_CSET_UTF8);
  hid_t s = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(f, name, t, s, H5P_DEFAULT, H5P_DEFAULT);
  const char* v = value.c_str();
  ASSERT_GE(H5Awrite(a, t, &v), 0);
  H5Aclose(a), H5Sclose(s), H5Tclose(t), H5Fclose(f);
  restampChecksum(path);
}

// A shape larger than the file can hold is refused before anything is read
// (reading it would allocate a terabyte).
TEST_F(TemplateFileBad, ImpossibleDatasetShape) {
  const std::string p = copy("huge.h5");
  hid_t f = H5Fopen(p.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  hid_t d = H5Dopen2(f, "/particles/phase", H5P_DEFAULT);
  const hsize_t rows = hsize_t(1) << 40;
  ASSERT_GE(H5Dset_extent(d, &rows), 0);
  H5Dclose(d), H5Fclose(f);
  restampChecksum(p);
  expectBad<3>(p, "dataset /particles/phase claims 1099511627776 rows, more than a file of", false);
  EXPECT_THROW(templateFileStats(p), TemplateError);
  EXPECT_EQ(readTemplateHeader(p).dimension, 3);
}

TEST_F(TemplateFileBad, StorageTemplatesDoNotUse) {
  // A filter templates do not use (HDF5's scale-offset, whose decoder
  // trusts its parameters).
  const std::string so = copy("scaleoffset.h5");
  hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
  const hsize_t chunk = 16;
  H5Pset_chunk(dcpl, 1, &chunk);
  H5Pset_scaleoffset(dcpl, H5Z_SO_INT, H5Z_SO_INT_MINBITS_DEFAULT);
  replacePhase(so, dcpl);
  H5Pclose(dcpl);
  expectBad<3>(so, "dataset /particles/phase uses HDF5 filter 6, which templates do not use", false);

  // Contiguous storage.
  const std::string contiguous = copy("contiguous.h5");
  replacePhase(contiguous, H5P_DEFAULT);
  expectBad<3>(contiguous, "dataset /particles/phase is not stored in chunks as templates are", false);

  // An object header of the HDF5 1.8 format (no signature, no checksum)
  // where the superblock points to the root group's.
  const std::string old = copy("hdf5_18.h5");
  std::string data = readFile(old);
  ASSERT_EQ(data.compare(512 + 48, 4, "OHDR"), 0);
  data[512 + 48] = 'X';
  std::ofstream(old, std::ios::binary | std::ios::trunc).write(data.data(), std::streamsize(data.size()));
  restampChecksum(old);
  expectBad<3>(old, "is damaged: its root group has no HDF5 1.10 object header");
}

TEST_F(TemplateFileBad, StringsThatAreNotNamesOrText) {
  const std::string utf8 = copy("utf8.h5");
  setString(utf8, "created_by", "flowclip \xff\xfe");
  expectBad<3>(utf8, "attribute 'created_by' is not valid UTF-8");
  const std::string name = copy("name.h5");
  setString(name, "name", "../escape");
  expectBad<3>(name, "has the name '../escape', not [A-Za-z0-9_-]{1,64}");
  const std::string format = copy("format.h5");
  setString(format, "format", std::string(100, 'x'));
  expectBad<3>(format, "format is '" + std::string(64, 'x') + "...'");
}

// --- sample for tests/test_template_h5py.py -------------------------------------

// With FLOWCLIP_TEMPLATE_SAMPLE_DIR set (by the pytest, which runs this test
// alone), writes sample2d.h5 and sample3d.h5 there, each with a JSON file of
// what readTemplate returns for it (file order), so that the pytest can check
// that decoding per templates/README.md with h5py gives the same values.
// Without it, writes them to a temporary directory (the C++ side of the check).
TEST(TemplateFileSample, WriteForH5py) {
  TempDir tmp;
  const char* env = std::getenv("FLOWCLIP_TEMPLATE_SAMPLE_DIR");
  const fs::path out = env && *env ? fs::path(env) : fs::path(tmp.file(""));
  auto write = [&](const auto& in, const std::string& stem) {
    constexpr int D = std::decay_t<decltype(in.frames[0].x[0])>::RowsAtCompileTime;
    const std::string path = (out / (stem + ".h5")).string();
    writeTemplate(path, in);
    const auto got = readTemplate<D>(path);
    nlohmann::json j;
    j["frames"] = nlohmann::json::array();
    for (const auto& fr : got.frames) {
      nlohmann::json jf;
      jf["x"] = nlohmann::json::array();
      jf["v"] = nlohmann::json::array();
      for (size_t i = 0; i < fr.size(); ++i) {
        jf["x"].push_back(std::vector<double>(fr.x[i].data(), fr.x[i].data() + D));
        jf["v"].push_back(std::vector<double>(fr.v[i].data(), fr.v[i].data() + D));
      }
      jf["mass"] = std::vector<double>(fr.mass.begin(), fr.mass.end());
      jf["phase"] = fr.phase;
      j["frames"].push_back(jf);
    }
    std::ofstream(out / (stem + ".json")) << j.dump();
    EXPECT_TRUE(fs::exists(path));
  };
  BlobSpec s;
  s.nx = 6, s.ny = 5, s.nz = 4, s.frames = 8, s.emptyFrame = 3;
  write(makeBlob<2>(s), "sample2d");
  write(makeBlob<3>(s), "sample3d");
}
