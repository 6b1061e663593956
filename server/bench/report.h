#pragma once
// What every benchmark report says besides its figures, and how it is
// written: the date (UTC), the exact command line, the build (version,
// compiler, flags, Real) and the machine (CPU, cores, threads used, OS,
// kernel, niceness, load average at the start and at the end), in
// DIR/NAME.md and DIR/NAME.json, published together (both or neither).
// Used by bench solver, control, scenes, service and accuracy.
#include <nlohmann/json.hpp>

#include <chrono>
#include <string>
#include <vector>

namespace fc::bench {

// The 1, 5 and 15 minute load averages (empty where /proc has none).
std::vector<double> loadAverages();
// The 1 minute load average (-1 where /proc has none).
double loadAverage();

// Now, in UTC, as ISO 8601 to the second: 2026-12-03T17:49:46Z.
std::string utcTimestamp();

// A number printed with a printf format: fmt(0.125, "%.2f") is "0.13".
std::string fmt(double v, const char* format = "%.6g");

// A markdown table: the header's cells, then each row's (already formatted;
// a row shorter than the header is padded with empty cells).
std::string markdownTable(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows);

class Report {
 public:
  // Starts the report of `flowclip bench NAME`: the date, the command line
  // and the load average are read now. `threads`: the OpenMP threads each
  // measured run uses.
  Report(std::string name, int threads);

  // The date, command, build and machine (load average at the start and
  // now) as JSON fields.
  nlohmann::json header() const;
  // The same as markdown lines, for a report's top.
  std::string markdownHeader() const;

  // Writes DIR/NAME.md (`title`, the header lines, then `markdown`) and
  // DIR/NAME.json (the header's fields, then those of the object `figures`),
  // creating DIR; the two replace the previous pair together. Throws
  // std::runtime_error naming the file that could not be written.
  void write(const std::string& dir, const std::string& title, const std::string& markdown,
             const nlohmann::json& figures) const;

 private:
  static std::string markdownHeader(const nlohmann::json& header);

  std::string name_, date_, command_;
  std::vector<double> loadAtStart_;
  int threads_;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace fc::bench
