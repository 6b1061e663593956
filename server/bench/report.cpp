#include "bench/report.h"

#include "core/types.h"
#include "io/staged_files.h"

#include <sys/resource.h>
#include <sys/utsname.h>

#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <stdexcept>
#include <thread>

// Given by server/CMakeLists.txt; a build configured otherwise says "unknown".
#ifndef FLOWCLIP_BUILD_TYPE
#define FLOWCLIP_BUILD_TYPE "unknown"
#endif
#ifndef FLOWCLIP_BUILD_FLAGS
#define FLOWCLIP_BUILD_FLAGS "unknown"
#endif

namespace fc::bench {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

std::string firstMatch(const char* path, const std::string& prefix) {
  std::ifstream f(path);
  for (std::string line; std::getline(f, line);)
    if (line.rfind(prefix, 0) == 0) return line.substr(prefix.size());
  return {};
}

std::string trim(std::string s, const char* chars = " \t\":") {
  s.erase(0, s.find_first_not_of(chars));
  s.erase(s.find_last_not_of(chars) + 1);
  return s;
}

std::string cpuModel() {
  const std::string model = trim(firstMatch("/proc/cpuinfo", "model name"));
  return model.empty() ? "unknown" : model;
}

std::string osName() {
  const std::string name = trim(firstMatch("/etc/os-release", "PRETTY_NAME="));
  return name.empty() ? "unknown" : name;
}

// A word the shell reads back as itself: bare when it is plain, else quoted.
std::string shellWord(const std::string& arg) {
  if (!arg.empty() && arg.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"
                                            "_-+=/.,:@%") == std::string::npos)
    return arg;
  std::string quoted = "'";
  for (char c : arg) {
    if (c == '\'') quoted += "'\\''";
    else quoted += c;
  }
  quoted += '\'';
  return quoted;
}

// This process's command line as typed (arguments NUL-separated in /proc).
std::string commandLine() {
  std::ifstream f("/proc/self/cmdline", std::ios::binary);
  const std::string raw((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  std::string line;
  for (size_t at = 0; at < raw.size();) {
    const size_t end = std::min(raw.find('\0', at), raw.size());
    if (!line.empty()) line += ' ';
    line += shellWord(raw.substr(at, end - at));
    at = end + 1;
  }
  return line;
}

std::string compiler() {
#if defined(__clang__)
  return "clang " __clang_version__;
#elif defined(__GNUC__)
  return "GCC " __VERSION__;
#else
  return "unknown";
#endif
}

// The vector extensions the build was compiled for (-march).
std::string vectorExtensions() {
  std::string isa;
#ifdef __AVX512F__
  isa += " AVX-512F";
#endif
#ifdef __AVX2__
  isa += " AVX2";
#endif
#ifdef __FMA__
  isa += " FMA";
#endif
#ifdef __SSE4_2__
  isa += " SSE4.2";
#endif
  return isa.empty() ? "baseline" : isa.substr(1);
}

json loadJson(const std::vector<double>& load) { return load.empty() ? json(nullptr) : json(load); }

std::string loadText(const json& load) {
  if (!load.is_array()) return "unknown";
  std::string s;
  for (double l : load) {
    if (!s.empty()) s += ' ';
    s += fmt(l, "%.2f");
  }
  return s;
}

void writeText(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f << text;
  f.close();
  if (!f) throw std::runtime_error("cannot write " + path);
}

}  // namespace

std::vector<double> loadAverages() {
  std::ifstream f("/proc/loadavg");
  std::vector<double> load(3);
  if (!(f >> load[0] >> load[1] >> load[2])) return {};
  return load;
}

double loadAverage() {
  const std::vector<double> load = loadAverages();
  return load.empty() ? -1 : load[0];
}

std::string utcTimestamp() {
  const std::time_t t = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&t, &utc);
  char b[32];
  std::strftime(b, sizeof b, "%Y-%m-%dT%H:%M:%SZ", &utc);
  return b;
}

std::string fmt(double v, const char* format) {
  char b[64];
  std::snprintf(b, sizeof b, format, v);
  return b;
}

std::string markdownTable(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  std::string md = "|";
  for (const auto& h : header) md += " " + h + " |";
  md += "\n|";
  for (size_t k = 0; k < header.size(); ++k) md += k == 0 ? "---|" : "---:|";
  md += "\n";
  for (const auto& row : rows) {
    md += "|";
    for (size_t k = 0; k < header.size(); ++k) md += " " + (k < row.size() ? row[k] : std::string()) + " |";
    md += "\n";
  }
  return md;
}

Report::Report(std::string name, int threads)
    : name_(std::move(name)),
      date_(utcTimestamp()),
      command_(commandLine()),
      loadAtStart_(loadAverages()),
      threads_(threads),
      start_(std::chrono::steady_clock::now()) {}

json Report::header() const {
  utsname u{};
  uname(&u);
  const int nice = getpriority(PRIO_PROCESS, 0);
  return {{"benchmark", name_},
          {"date", date_},
          {"command", command_},
          {"duration_s", std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count()},
          {"flowclip",
           {{"version", FLOWCLIP_VERSION},
            {"build_type", FLOWCLIP_BUILD_TYPE},
            {"build_flags", trim(FLOWCLIP_BUILD_FLAGS, " ")},
            {"compiler", compiler()},
            {"vector_extensions", vectorExtensions()},
            {"real", realName()}}},
          {"machine",
           {{"cpu", cpuModel()},
            {"cores", std::thread::hardware_concurrency()},
            {"threads", threads_},
            {"os", osName()},
            {"kernel", std::string(u.sysname) + " " + u.release + " " + u.machine},
            {"niceness", nice},
            {"loadavg_at_start", loadJson(loadAtStart_)},
            {"loadavg_at_end", loadJson(loadAverages())}}}};
}

std::string Report::markdownHeader() const { return markdownHeader(header()); }

std::string Report::markdownHeader(const json& h) {
  const json& b = h["flowclip"];
  const json& m = h["machine"];
  std::ostringstream md;
  md << "- date: " << h["date"].get<std::string>() << "\n"
     << "- command: `" << h["command"].get<std::string>() << "`\n"
     << "- flowclip " << b["version"].get<std::string>() << ", " << b["build_type"].get<std::string>() << " build ("
     << b["compiler"].get<std::string>() << ", `" << b["build_flags"].get<std::string>() << "`, "
     << b["vector_extensions"].get<std::string>() << "), Real = " << b["real"].get<std::string>() << "\n"
     << "- machine: " << m["cpu"].get<std::string>() << ", " << m["cores"] << " cores, " << m["threads"]
     << " OpenMP thread" << (m["threads"] == 1 ? "" : "s") << " per run; " << m["os"].get<std::string>() << ", "
     << m["kernel"].get<std::string>() << "; niceness " << m["niceness"] << "\n"
     << "- load average (1, 5, 15 min): " << loadText(m["loadavg_at_start"]) << " at the start, "
     << loadText(m["loadavg_at_end"]) << " at the end; the benchmark took "
     << fmt(h["duration_s"].get<double>(), "%.0f") << " s\n";
  return md.str();
}

void Report::write(const std::string& dir, const std::string& title, const std::string& markdown,
                   const json& figures) const {
  if (!figures.is_object()) throw std::logic_error("a report's figures are a JSON object");
  fs::create_directories(dir);
  json all = header();
  const std::string md = "# " + title + "\n\n" + markdownHeader(all) + "\n" + markdown;
  for (const auto& [key, value] : figures.items()) all[key] = value;
  // Both staged beside their names: a reader sees the old pair or the new one.
  StagedFiles publish(/*replace=*/true);
  const std::vector<std::pair<std::string, std::string>> files = {
      {(fs::path(dir) / (name_ + ".md")).string(), md},
      {(fs::path(dir) / (name_ + ".json")).string(), all.dump(2) + "\n"}};
  for (const auto& [path, text] : files) {
    const std::string staged = stagingPath(path);
    publish.stage(staged, path);
    writeText(staged, text);
  }
  publish.commit();
  std::fprintf(stderr, "bench %s: wrote %s and %s.json\n", name_.c_str(), files[0].first.c_str(), name_.c_str());
}

}  // namespace fc::bench
