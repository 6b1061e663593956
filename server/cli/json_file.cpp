#include "cli/json_file.h"
#include "io/staged_files.h"
#include <nlohmann/json.hpp>

namespace fc::cli {

void writeJsonAtomically(const std::string& path, const nlohmann::json& j) {
  // Hidden staging name and fsync (io/staged_files.h): a crash leaves the old file or the new one.
  publishFile(path, j.dump(1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n", true);
}

}  // namespace fc::cli
