// `flowclip` of a portable install (make portable, docs/portable.md): picks
// the executable built for the best x86-64 level this CPU runs, next to
// itself (flowclip-x86-64-v4 with AVX-512, else flowclip-x86-64-v3 with
// AVX2 and FMA), and runs it in its place with the same arguments. Built
// for the x86-64 baseline, so that it starts on any x86-64 CPU and can say
// why when none of the executables would.
//
// FLOWCLIP_CPU_LEVEL=x86-64-v3 (or v4) picks a level by hand: to compare
// them on one machine, or to keep a farm's nodes on the same code path.
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <unistd.h>
#include <vector>

namespace {

struct Level {
  const char* name;
  bool (*supported)();
};

bool v3() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && __builtin_cpu_supports("bmi2");
}
bool v4() {
  return v3() && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
         __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
}
// The best first.
const Level kLevels[] = {{"x86-64-v4", v4}, {"x86-64-v3", v3}};

std::string ownDirectory() {
  std::vector<char> buf(4096);
  const ssize_t n = ::readlink("/proc/self/exe", buf.data(), buf.size() - 1);
  if (n <= 0) return ".";
  std::string path(buf.data(), size_t(n));
  const size_t slash = path.rfind('/');
  return slash == std::string::npos ? "." : path.substr(0, slash);
}

}  // namespace

int main(int argc, char** argv) {
  const std::string dir = ownDirectory();
  const char* forced = std::getenv("FLOWCLIP_CPU_LEVEL");
  if (forced && *forced) {
    const Level* level = nullptr;
    for (const Level& l : kLevels)
      if (std::strcmp(l.name, forced) == 0) level = &l;
    if (!level) {
      std::fprintf(stderr, "flowclip: FLOWCLIP_CPU_LEVEL=%s is not one of x86-64-v4, x86-64-v3\n", forced);
      return 2;
    }
    if (!level->supported()) {
      std::fprintf(stderr, "flowclip: FLOWCLIP_CPU_LEVEL=%s: this CPU lacks its instructions\n", forced);
      return 2;
    }
    const std::string path = dir + "/flowclip-" + level->name;
    ::execv(path.c_str(), argv);
    std::fprintf(stderr, "flowclip: cannot run %s: %s\n", path.c_str(), std::strerror(errno));
    return 2;
  }
  for (const Level& level : kLevels) {
    if (!level.supported()) continue;
    const std::string path = dir + "/flowclip-" + level.name;
    if (::access(path.c_str(), X_OK) != 0) continue;  // a level not installed: the next one
    ::execv(path.c_str(), argv);
    std::fprintf(stderr, "flowclip: cannot run %s: %s\n", path.c_str(), std::strerror(errno));
    return 2;
  }
  std::fprintf(stderr,
               "flowclip: no executable in %s runs on this CPU: FlowClip needs x86-64-v3 (AVX2, FMA, BMI2; "
               "Intel Haswell, AMD Zen and later)\n",
               dir.c_str());
  (void)argc;
  return 2;
}
