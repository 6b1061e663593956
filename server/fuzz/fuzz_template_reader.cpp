// Fuzz target: template files (io/template_file.h). The bytes are a template
// file's content; they are written to a per-process temporary file and read
// the ways the program reads one: readTemplateHeader (listing, inspect),
// templateFileStats, readTemplate<2> and readTemplate<3> (loading), and
// TemplateStream<2|3> frame by frame (streaming).
//
// Documented outcome for a bad file: fc::TemplateError whose message names
// the file. Anything else escaping is a finding (libFuzzer reports the
// std::terminate abort), and so is a message without the file's path. For a
// file that reads, the readers must agree: readTemplate<D> succeeds only for
// D = the header's dimension, with the header readTemplateHeader gives and
// the frame and particle counts templateFileStats gives.
//
// Seeds (corpus/template_reader/): tiny2d.h5, written by writeTemplate (with
// its checksum block: nearly every mutation stops at the checksum);
// tiny2d-unchecked.h5, the same template written before checksum blocks
// existed (mutations reach HDF5 through the reader's structural checks);
// crash-vlen-string-attr.h5, that file with one bit flipped in the size of a
// string in HDF5's global heap, which crashed HDF5 before those checks.
// FLOWCLIP_FUZZ_TMPDIR chooses the directory of the temporary file.
#include "fuzz_support.h"
#include "io/template_file.h"

#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>

namespace {

const std::string& inputPath() {
  // Never destroyed: the exit handler that removes the file still reads it.
  static const std::string* const path = [] {
    const std::string dir = fc::fuzz::env("FLOWCLIP_FUZZ_TMPDIR", std::filesystem::temp_directory_path().string());
    auto* p = new std::string(dir + "/flowclip-fuzz-template-" + std::to_string(::getpid()) + ".h5");
    std::atexit([] { std::remove(inputPath().c_str()); });
    return p;
  }();
  return *path;
}

// Runs one reader: true if it returned, false if it threw TemplateError
// (which must name the file). Other exceptions escape.
template <class Read>
bool attempt(const char* reader, Read&& read) {
  try {
    read();
    return true;
  } catch (const fc::TemplateError& e) {
    const std::string message = e.what();
    FUZZ_CHECK(message.find(inputPath()) != std::string::npos,
               std::string(reader) + "'s error does not name the file: " + message);
    return false;
  }
}

template <int D>
void checkAgainst(const fc::Template<D>& tpl, const std::optional<fc::TemplateHeader>& header,
                  const std::optional<fc::TemplateFileStats>& stats) {
  FUZZ_CHECK(header.has_value(), "readTemplate<" + std::to_string(D) + "> read a file whose header does not");
  FUZZ_CHECK(header->dimension == D, "readTemplate<" + std::to_string(D) + "> read a " +
                                         std::to_string(header->dimension) + "D template");
  FUZZ_CHECK(tpl.header.name == header->name && tpl.header.recipe == header->recipe &&
                 tpl.header.regionMin == header->regionMin && tpl.header.regionMax == header->regionMax,
             "readTemplate and readTemplateHeader disagree on the header of " + header->name);
  FUZZ_CHECK(stats.has_value(), "readTemplate read a file templateFileStats refuses");
  size_t lo = 0, hi = 0, total = 0;
  for (size_t f = 0; f < tpl.frames.size(); ++f) {
    const auto& fr = tpl.frames[f];
    FUZZ_CHECK(fr.v.size() == fr.size() && fr.mass.size() == fr.size() && fr.phase.size() == fr.size(),
               "frame " + std::to_string(f) + " has particle arrays of different lengths");
    lo = f == 0 ? fr.size() : std::min(lo, fr.size());
    hi = std::max(hi, fr.size());
    total += fr.size();
  }
  FUZZ_CHECK(stats->frames == tpl.frames.size() && stats->minParticles == lo && stats->maxParticles == hi &&
                 (stats->frames == 0 || stats->avgParticles == double(total) / double(stats->frames)),
             "templateFileStats and readTemplate disagree: " + std::to_string(stats->frames) + " frames of " +
                 std::to_string(stats->minParticles) + ".." + std::to_string(stats->maxParticles) + " vs " +
                 std::to_string(tpl.frames.size()) + " of " + std::to_string(lo) + ".." + std::to_string(hi));
}

// The streamed reader (TemplateStream<D>, frame by frame from the disk)
// reads what readTemplate<D> reads, frame for frame; a file readTemplate
// refuses may open as a stream, but then some frame must be refused.
template <int D>
void checkStream(const std::optional<fc::Template<D>>& whole) {
  std::optional<fc::TemplateStream<D>> stream;
  attempt("TemplateStream", [&] { stream.emplace(inputPath()); });
  if (!stream) return;
  bool refused = false;
  for (size_t f = 0; f < stream->frameCount(); ++f) {
    std::optional<fc::TemplateFrame<D>> frame;
    if (!attempt("TemplateStream::readFrame", [&] { frame = stream->readFrame(f); })) {
      FUZZ_CHECK(!whole, "TemplateStream refused frame " + std::to_string(f) + " of a file readTemplate reads");
      refused = true;
      continue;
    }
    if (!whole) continue;
    const auto& w = whole->frames.at(f);
    FUZZ_CHECK(frame->x == w.x && frame->v == w.v && frame->mass == w.mass && frame->phase == w.phase,
               "TemplateStream and readTemplate read frame " + std::to_string(f) + " differently");
  }
  FUZZ_CHECK(whole || refused, "TemplateStream read every frame of a file readTemplate refuses");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = inputPath();
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), std::streamsize(size));
    out.close();
    FUZZ_CHECK(out.good(), "cannot write the input to " + path);
  }
  std::optional<fc::TemplateHeader> header;
  std::optional<fc::TemplateFileStats> stats;
  attempt("readTemplateHeader", [&] { header = fc::readTemplateHeader(path); });
  attempt("templateFileStats", [&] { stats = fc::templateFileStats(path); });
  FUZZ_CHECK(!stats || stats->bytesOnDisk == size, "templateFileStats gives " + std::to_string(stats->bytesOnDisk) +
                                                       " bytes for a file of " + std::to_string(size));
  FUZZ_CHECK(!stats || (header && stats->header.name == header->name && stats->header.recipe == header->recipe &&
                        stats->header.dimension == header->dimension),
             "templateFileStats read a header readTemplateHeader refuses or reads differently");
  std::optional<fc::Template<2>> t2;
  std::optional<fc::Template<3>> t3;
  attempt("readTemplate<2>", [&] { t2 = fc::readTemplate<2>(path); });
  attempt("readTemplate<3>", [&] { t3 = fc::readTemplate<3>(path); });
  if (t2) checkAgainst(*t2, header, stats);
  if (t3) checkAgainst(*t3, header, stats);
  checkStream<2>(t2);
  checkStream<3>(t3);
  return 0;
}
