#pragma once
// JSON text from users (scene files, REST bodies, WebSocket edits) parsed
// with the checks every such input needs: a nesting limit (copying and
// comparing json values recurse, so depth is stack), duplicate keys (plain
// parsers keep the last silently), and errors that say where: line and
// column for syntax, the key path for a number out of range.
#include <nlohmann/json.hpp>

#include <stdexcept>
#include <string>

namespace fc {

struct JsonTextError : std::runtime_error {
  enum class Kind { Syntax, TooDeep, DuplicateKey, NumberOutOfRange };
  JsonTextError(Kind kind, std::string path, std::string where, const std::string& message);
  Kind kind;
  std::string path;   // key path of the offending value ("instances[2].speed"), "" at the top
  std::string where;  // "line:column" when known, else ""
  std::string detail; // what() without location
};

struct JsonTextOptions {
  int maxDepth = 128;
  bool rejectDuplicateKeys = true;
};

// Throws JsonTextError.
nlohmann::json parseJsonText(const std::string& text, const JsonTextOptions& options = {});

// "a.b[2]" path helpers shared by every validator.
std::string jsonKeyPath(const std::string& path, const std::string& key);
std::string jsonIndexPath(const std::string& path, size_t index);

}  // namespace fc
