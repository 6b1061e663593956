#pragma once
// JSON results the commands write (--stats, --out).
#include <nlohmann/json_fwd.hpp>
#include <string>

namespace fc::cli {

// Writes j to a temporary name next to `path`, then renames: a reader never
// sees half a file, and a failed write leaves an existing file as it was.
// Throws std::runtime_error naming the path.
void writeJsonAtomically(const std::string& path, const nlohmann::json& j);

}  // namespace fc::cli
