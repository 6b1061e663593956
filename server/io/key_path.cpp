#include "io/key_path.h"

#include <vector>

namespace fc {

namespace {

struct Token {
  bool item;         // [..] rather than a key
  std::string name;  // the key, or what is inside the brackets
};

std::vector<Token> tokens(const std::string& path) {
  const auto bad = [&] { return KeyPathError(path + ": not a key path (a.b, list[NAME], list[3])"); };
  std::vector<Token> out;
  size_t i = 0;
  while (i < path.size()) {
    if (path[i] == '[') {
      const size_t close = path.find(']', i);
      if (close == std::string::npos || out.empty()) throw bad();
      out.push_back({true, path.substr(i + 1, close - i - 1)});
      i = close + 1;
    } else {
      if (path[i] == '.') {
        if (out.empty() || i + 1 >= path.size()) throw bad();
        ++i;
      } else if (!out.empty()) {
        throw bad();  // a key must follow '.' or start the path
      }
      const size_t end = path.find_first_of(".[]", i);
      const size_t stop = end == std::string::npos ? path.size() : end;
      if (stop == i || (end != std::string::npos && path[end] == ']')) throw bad();
      out.push_back({false, path.substr(i, stop - i)});
      i = stop;
    }
  }
  if (out.empty() || out.front().item) throw bad();
  return out;
}

bool isIndex(const std::string& s) {
  return !s.empty() && s.size() < 9 && s.find_first_not_of("0123456789") == std::string::npos;
}

}  // namespace

void setKeyPath(nlohmann::json& scene, const std::string& path, const nlohmann::json& value) {
  const std::vector<Token> ts = tokens(path);
  nlohmann::json* node = &scene;
  std::string where;
  for (size_t n = 0; n < ts.size(); ++n) {
    const bool last = n + 1 == ts.size();
    const Token& t = ts[n];
    if (!t.item) {
      if (!node->is_object()) throw KeyPathError(path + ": " + (where.empty() ? "the scene" : where) + " is not an object");
      if (last) {
        (*node)[t.name] = value;
        return;
      }
      if (!node->contains(t.name))
        throw KeyPathError(path + ": the scene has no " + (where.empty() ? "" : where + ".") + t.name);
      node = &(*node)[t.name];
      where += (where.empty() ? "" : ".") + t.name;
    } else {
      if (!node->is_array()) throw KeyPathError(path + ": " + where + " is not a list");
      size_t index = 0;
      if (isIndex(t.name)) {
        index = std::stoul(t.name);
        if (index >= node->size())
          throw KeyPathError(path + ": " + where + " has " + std::to_string(node->size()) + " elements");
      } else {
        std::string names;
        bool found = false;
        for (size_t i = 0; i < node->size(); ++i) {
          const nlohmann::json& e = (*node)[i];
          if (!e.is_object() || !e.contains("name") || !e["name"].is_string()) continue;
          if (!found && e["name"] == t.name) {
            index = i;
            found = true;
          }
          names += (names.empty() ? "" : ", ") + e["name"].get<std::string>();
        }
        if (!found)
          throw KeyPathError(path + ": no element of " + where + " named \"" + t.name + "\" (names: " + names + ")");
      }
      if (last) {
        (*node)[index] = value;
        return;
      }
      node = &(*node)[index];
      where += "[" + t.name + "]";
    }
  }
}

}  // namespace fc
