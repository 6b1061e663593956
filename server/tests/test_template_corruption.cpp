// Damaged template files (io/template_file.h, templates/README.md "Reader
// checks"): a flipped bit anywhere is either read back consistently or
// refused with a TemplateError naming the file, never a crash. Files with a
// checksum block refuse every single-bit change; files written before
// checksums (format_version 1 without the block) still read, with their
// string storage (HDF5's global heap, which HDF5 1.10 does not checksum)
// checked before HDF5 parses it.
//
// The files without a checksum block come from the fuzz corpus
// (server/fuzz/corpus/template_reader/): tiny2d-unchecked.h5 was written by
// the writer before checksums, crash-vlen-string-attr.h5 is the same file
// with one bit flipped in the size of its first string, which used to crash
// HDF5 inside the read of the 'format' attribute.
#include "io/template_file.h"
#include "tests/hdf5_test_util.h"

#include <gtest/gtest.h>
#include <hdf5.h>
#include <zlib.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

using namespace fc;
using fc::test::readFile;
using fc::test::TempDir;

namespace {

const std::string kCorpus = std::string(FLOWCLIP_SOURCE_DIR) + "/server/fuzz/corpus/template_reader/";

void writeBytes(const std::string& path, const std::string& data) {
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(data.data(), std::streamsize(data.size()));
}

// A small 2D template: 4 frames of 0 to 30 particles, two phases.
Template<2> smallTemplate() {
  Template<2> t;
  TemplateHeader& h = t.header;
  h.name = "small2d";
  h.dimension = 2;
  h.frameRate = 30;
  h.particleRadius = 0.01;
  h.supportRadius = 0.04;
  h.restDensity = 1000;
  h.regionMin = {0.0, 0.0};
  h.regionMax = {0.3, 0.3};
  h.recipe = R"({"dimension": 2, "name": "small2d", "note": "corruption tests"})";
  h.createdBy = "flowclip tests";
  for (int f = 0; f < 4; ++f) {
    TemplateFrame<2> fr;
    for (int i = 0; i < (f == 2 ? 0 : 10 * (f + 1)); ++i) {
      Vec<2> x, v;
      x[0] = Real(0.02 + 0.02 * (i % 6) + 0.003 * f);
      x[1] = Real(0.02 + 0.02 * (i / 6) - 0.001 * f);
      v[0] = Real(0.05 * f - 0.01 * i);
      v[1] = Real(-0.2 * f);
      fr.x.push_back(x);
      fr.v.push_back(v);
      fr.mass.push_back(Real(i % 3 == 0 ? 0.32 : 0.4));
      fr.phase.push_back(uint8_t(i % 3 == 0));
    }
    t.frames.push_back(fr);
  }
  return t;
}

// Reads `path` with readTemplateHeader, templateFileStats and
// readTemplate<2>. Each must either succeed or throw a TemplateError naming
// the file; what succeeds must agree with the other readers. Returns how
// many succeeded; anything wrong is appended to `problems`, after `what`
// (the corruption).
int readAll(const std::string& path, const std::string& what, std::string& problems) {
  int ok = 0;
  auto problem = [&](const std::string& text) { problems += what + ": " + text + "\n"; };
  auto attempt = [&](const char* reader, auto&& read) {
    try {
      read();
      ++ok;
    } catch (const TemplateError& e) {
      if (std::string(e.what()).find(path) == std::string::npos)
        problem(std::string(reader) + "'s message does not name the file: " + e.what());
    } catch (const std::exception& e) {
      problem(std::string(reader) + " threw something else than TemplateError: " + e.what());
    }
  };
  std::optional<TemplateHeader> header;
  std::optional<TemplateFileStats> stats;
  std::optional<Template<2>> tpl;
  attempt("readTemplateHeader", [&] { header = readTemplateHeader(path); });
  attempt("templateFileStats", [&] { stats = templateFileStats(path); });
  attempt("readTemplate<2>", [&] { tpl = readTemplate<2>(path); });
  if (header && stats && (stats->header.name != header->name || stats->header.recipe != header->recipe))
    problem("templateFileStats and readTemplateHeader disagree on the header");
  if (!tpl) return ok;
  if (!header || !stats) problem("readTemplate<2> succeeded where the header or the stats failed");
  if (header && (header->name != tpl->header.name || header->dimension != 2 || header->recipe != tpl->header.recipe))
    problem("readTemplateHeader and readTemplate<2> disagree on the header");
  if (stats) {
    size_t lo = SIZE_MAX, hi = 0;
    for (const auto& fr : tpl->frames) {
      lo = std::min(lo, fr.size());
      hi = std::max(hi, fr.size());
      if (fr.v.size() != fr.size() || fr.mass.size() != fr.size() || fr.phase.size() != fr.size())
        problem("a frame's particle arrays differ in length");
    }
    if (stats->frames != tpl->frames.size() || (!tpl->frames.empty() && (stats->minParticles != lo || stats->maxParticles != hi)))
      problem("templateFileStats and readTemplate<2> disagree on the frames");
  }
  return ok;
}

// Writes each corruption of `data` that `corrupt` makes (it calls its
// argument with a byte offset and an XOR mask) to `path` and reads it with
// readAll, in a child process: a crash fails this test only, and so does
// anything readAll finds or fewer than `minRefusedPercent` % of the
// corruptions refused. HDF5's leaks on its error paths stay in the child.
template <class Corrupt>
void flipInChild(const std::string& data, const std::string& path, size_t minRefusedPercent, Corrupt corrupt) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  auto child = [&] {
    std::string problems;
    size_t flips = 0, refused = 0;
    corrupt([&](size_t i, uint8_t mask) {
      std::string bad = data;
      bad[i] = char(bad[i] ^ mask);
      writeBytes(path, bad);
      refused += readAll(path, "byte " + std::to_string(i) + " ^ " + std::to_string(mask), problems) == 0;
      ++flips;
    });
    if (refused * 100 < flips * minRefusedPercent)
      problems += std::to_string(refused) + " of " + std::to_string(flips) + " corruptions refused, expected " +
                  std::to_string(minRefusedPercent) + " %\n";
    std::fprintf(stderr, "%zu corruptions, %zu refused\n%s", flips, refused, problems.substr(0, 4000).c_str());
    std::fflush(stderr);
    // _Exit skips the child's destructors: remove its directory here.
    std::error_code ec;
    std::filesystem::remove_all(std::filesystem::path(path).parent_path(), ec);
    std::_Exit(problems.empty() ? 0 : 1);
  };
  EXPECT_EXIT(child(), ::testing::ExitedWithCode(0), "corruptions");
}

// Where the global heap collection of an unchecked file starts, and the
// offsets of its objects' headers (index: 2 bytes, then 6, then size: 8).
struct GlobalHeap {
  size_t at = 0;
  std::vector<size_t> objects;  // the string objects, then the free space
};

GlobalHeap globalHeap(const std::string& data) {
  GlobalHeap g;
  g.at = data.find(std::string("GCOL\x01", 5));
  if (g.at == std::string::npos) return g;
  auto le = [&](size_t p, int n) {
    uint64_t v = 0;
    for (int i = n - 1; i >= 0; --i) v = v << 8 | uint8_t(data[p + size_t(i)]);
    return v;
  };
  const uint64_t size = le(g.at + 8, 8);
  for (uint64_t p = 16; p + 16 <= size;) {
    g.objects.push_back(g.at + p);
    const uint64_t index = le(g.at + p, 2), n = le(g.at + p + 8, 8);
    if (index == 0) break;
    p += 16 + (n + 7) / 8 * 8;
  }
  return g;
}

}  // namespace

TEST(TemplateCorruption, FilesWithoutChecksumStillRead) {
  const std::string path = kCorpus + "tiny2d-unchecked.h5";
  ASSERT_EQ(readFile(path).compare(0, 4, "\x89HDF"), 0) << "expected a file without a checksum block";
  const Template<2> t = readTemplate<2>(path);
  EXPECT_EQ(t.header.name, "tiny2d");
  ASSERT_EQ(t.frames.size(), 3u);
  for (const auto& fr : t.frames) EXPECT_EQ(fr.size(), 12u);
  const TemplateFileStats s = templateFileStats(path);
  EXPECT_FALSE(s.checksummed);
  EXPECT_EQ(s.header.name, "tiny2d");
  EXPECT_EQ(s.bytesOnDisk, readFile(path).size());
  EXPECT_EQ(readTemplateHeader(path).recipe, R"({"dimension": 2, "name": "tiny2d"})");

  // The corpus's checksummed twin, written by today's writer, reads the same.
  const std::string twin = kCorpus + "tiny2d.h5";
  EXPECT_TRUE(templateFileStats(twin).checksummed);
  EXPECT_EQ(readTemplate<2>(twin).frames[2].x, t.frames[2].x);
}

TEST(TemplateCorruption, ChecksumBlockIsAsDocumented) {
  TempDir dir;
  const std::string path = dir.file("t.h5");
  writeTemplate(path, smallTemplate());
  const std::string data = readFile(path);
  ASSERT_GT(data.size(), 512u);
  const uLong crc = crc32_z(0, reinterpret_cast<const Bytef*>(data.data() + 512), data.size() - 512);
  char text[96];
  std::snprintf(text, sizeof text, "FLOWCLIP TEMPLATE\ncrc32 %08lx\nlength %zu\n", crc, data.size() - 512);
  std::string block(text);
  block.resize(512, '\0');
  EXPECT_EQ(data.substr(0, 512), block);
  EXPECT_EQ(data.compare(512, 4, "\x89HDF"), 0);
  EXPECT_TRUE(templateFileStats(path).checksummed);

  // HDF5 itself (any HDF5 tool) opens it: the block is an HDF5 user block.
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  hid_t fcpl = H5Fget_create_plist(f);
  hsize_t userblock = 0;
  H5Pget_userblock(fcpl, &userblock);
  EXPECT_EQ(userblock, 512u);
  H5Pclose(fcpl);
  EXPECT_GT(H5Aexists(f, "format"), 0);
  H5Fclose(f);
}

TEST(TemplateCorruption, TruncatedOrExtendedFileIsRefused) {
  TempDir dir;
  const std::string path = dir.file("t.h5");
  writeTemplate(path, smallTemplate());
  const std::string data = readFile(path);
  const std::string cut = dir.file("cut.h5"), longer = dir.file("longer.h5"), tiny = dir.file("tiny.h5");
  writeBytes(cut, data.substr(0, data.size() - 1));
  writeBytes(longer, data + '\0');
  writeBytes(tiny, data.substr(0, 100));
  for (const std::string& p : {cut, longer, tiny}) {
    try {
      readTemplateHeader(p);
      ADD_FAILURE() << p << " was read";
    } catch (const TemplateError& e) {
      EXPECT_NE(std::string(e.what()).find(p), std::string::npos) << e.what();
      EXPECT_TRUE(std::string(e.what()).find("truncated or damaged") != std::string::npos ||
                  std::string(e.what()).find("checksum block") != std::string::npos)
          << e.what();
    }
  }
}

// Every single-bit change of a checksummed file is refused: CRC-32 detects
// them all, and the block itself must be exactly as written.
TEST(TemplateCorruption, BitFlipsOfAChecksummedFileAreRefused) {
  TempDir dir;
  const std::string good = dir.file("good.h5");
  writeTemplate(good, smallTemplate());
  const std::string data = readFile(good);
  ASSERT_GT(data.size(), 4096u);
  flipInChild(data, dir.file("flipped.h5"), 100, [&](auto flip) {
    // Every bit of the block's text and of the superblock after it; one bit
    // of every byte of the block and the root group; every 13th byte after.
    for (size_t i = 0; i < data.size(); ++i) {
      if (i < 64 || (i >= 512 && i < 560))
        for (int b = 0; b < 8; ++b) flip(i, uint8_t(1u << b));
      else if (i < 1200 || i % 13 == 0)
        flip(i, uint8_t(1u << (i * 5 % 8)));
    }
  });
}

// A file without a checksum block: every byte up to the end of the string
// storage (superblock, root group, attribute heap and index, global heap)
// flipped, one bit each, plus whole-byte inversions of every 8th of those
// and one bit of every 11th byte after.
TEST(TemplateCorruption, BitFlipsInAFileWithoutChecksumNeverCrash) {
  TempDir dir;
  const std::string data = readFile(kCorpus + "tiny2d-unchecked.h5");
  const GlobalHeap heap = globalHeap(data);
  ASSERT_NE(heap.at, std::string::npos);
  ASSERT_FALSE(heap.objects.empty());
  const size_t head = heap.objects.back() + 16;  // through the free space's header
  ASSERT_LT(head, data.size());
  // Most metadata flips are caught (HDF5's own checksums, the checks before
  // it); some land in bytes nobody reads (reserved fields, string text).
  flipInChild(data, dir.file("flipped.h5"), 35, [&](auto flip) {
    for (size_t i = 0; i < data.size(); ++i) {
      if (i < head || i % 11 == 0) flip(i, uint8_t(1u << (i * 5 % 8)));
      if (i < head && i % 8 == 0) flip(i, 0xFF);
    }
  });
}

// The crash this guards against: HDF5 1.10 trusts the object sizes and
// indices of its global heap, where variable-length strings live.
TEST(TemplateCorruption, DamagedStringStorageIsAnError) {
  const std::string crash = kCorpus + "crash-vlen-string-attr.h5";
  try {
    readTemplateHeader(crash);
    ADD_FAILURE() << "read " << crash;
  } catch (const TemplateError& e) {
    EXPECT_NE(std::string(e.what()).find(crash), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("global heap"), std::string::npos) << e.what();
  }

  TempDir dir;
  const std::string path = dir.file("heap.h5");
  const std::string data = readFile(kCorpus + "tiny2d-unchecked.h5");
  const GlobalHeap heap = globalHeap(data);
  ASSERT_GE(heap.objects.size(), 8u);  // seven strings, then the free space
  struct Damage {
    size_t at;
    std::string bytes;
    const char* what;
  };
  const size_t first = heap.objects[0], second = heap.objects[1], free = heap.objects.back();
  const std::vector<Damage> damages = {
      {heap.at + 8, std::string("\x00\x00\x00\x00\x00\x01\x00\x00", 8), "collection size beyond the file"},
      {heap.at + 8, std::string("\x10\x00\x00\x00\x00\x00\x00\x00", 8), "collection size too small"},
      {first + 8, std::string("\xff\xff\xff\xff\xff\xff\xff\x7f", 8), "huge string size"},
      {first + 10, std::string("\x01", 1), "string size past the next object"},
      {first + 8, std::string("\x13", 1), "string size into its zero padding"},
      {first + 8, std::string("\x08", 1), "string size shrunk (the next object misplaced)"},
      {first, std::string("\x09\x00", 2), "object index out of order"},
      {second, std::string("\x01\x00", 2), "object index repeated"},
      {first, std::string("\x00\x00", 2), "free space in the middle"},
      {free + 8, std::string("\x00\x00\x00\x00\x00\x00\x00\x00", 8), "free space of size 0 (HDF5 loops forever)"},
      {first + 16, std::string("\x00", 1), "NUL inside a string"},
  };
  for (const Damage& d : damages) {
    std::string bad = data;
    bad.replace(d.at, d.bytes.size(), d.bytes);
    writeBytes(path, bad);
    try {
      readTemplateHeader(path);
      ADD_FAILURE() << d.what << ": read";
    } catch (const TemplateError& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << d.what << ": " << e.what();
      EXPECT_NE(std::string(e.what()).find("global heap"), std::string::npos) << d.what << ": " << e.what();
    }
    std::string problems;
    EXPECT_EQ(readAll(path, d.what, problems), 0) << d.what;
    EXPECT_EQ(problems, "");
  }
}
