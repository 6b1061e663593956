#include "io/json_text.h"

#include "core/text.h"

#include <set>
#include <vector>

namespace fc {

using json = nlohmann::json;

JsonTextError::JsonTextError(Kind k, std::string p, std::string w, const std::string& message)
    : std::runtime_error(message), kind(k), path(std::move(p)), where(std::move(w)), detail(message) {}

std::string jsonKeyPath(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}
std::string jsonIndexPath(const std::string& path, size_t index) { return path + "[" + std::to_string(index) + "]"; }

namespace {

// Where the parser is, kept outside the callback (nlohmann copies it).
struct PathTracker {
  struct Frame {
    bool array = false;
    size_t index = 0;
    std::string key;
    bool hasKey = false;
    std::set<std::string> keys;
  };
  std::vector<Frame> stack;
  JsonTextOptions options;

  std::string path() const {
    std::string p;
    for (const Frame& f : stack) {
      if (f.array) p = jsonIndexPath(p, f.index);
      else if (f.hasKey) p = jsonKeyPath(p, f.key);
    }
    return p;
  }
  void childDone() {
    if (!stack.empty()) {
      if (stack.back().array) ++stack.back().index;
      else stack.back().hasKey = false;
    }
  }
  bool event(int depth, json::parse_event_t ev, json& parsed) {
    switch (ev) {
      case json::parse_event_t::object_start:
      case json::parse_event_t::array_start:
        if (depth >= options.maxDepth)
          throw JsonTextError(JsonTextError::Kind::TooDeep, path(), "",
                              "JSON nested deeper than " + std::to_string(options.maxDepth) + " levels");
        stack.emplace_back();
        stack.back().array = ev == json::parse_event_t::array_start;
        break;
      case json::parse_event_t::key: {
        Frame& f = stack.back();
        f.key = parsed.get<std::string>();
        f.hasKey = true;
        if (options.rejectDuplicateKeys && !f.keys.insert(f.key).second)
          throw JsonTextError(JsonTextError::Kind::DuplicateKey, path(), "",
                              "duplicate key; each key may appear once per object");
        break;
      }
      case json::parse_event_t::object_end:
      case json::parse_event_t::array_end:
        stack.pop_back();
        childDone();
        break;
      case json::parse_event_t::value: childDone(); break;
    }
    return true;
  }
};

std::string lineColumn(const std::string& text, size_t offset) {
  offset = std::min(offset, text.size());
  size_t line = 1, lineStart = 0;
  for (size_t i = 0; i < offset; ++i)
    if (text[i] == '\n') ++line, lineStart = i + 1;
  return std::to_string(line) + ":" + std::to_string(offset - lineStart + 1);
}

// nlohmann's what() is "[json.exception.x.N] detail": keep the detail, as
// printable text (it quotes the offending bytes).
std::string detailOf(const json::exception& e) {
  std::string d = e.what();
  const size_t close = d.find("] ");
  if (close != std::string::npos) d = d.substr(close + 2);
  return printable(d, 300);
}

}  // namespace

json parseJsonText(const std::string& text, const JsonTextOptions& options) {
  PathTracker tracker;
  tracker.options = options;
  const json::parser_callback_t cb = [&tracker](int depth, json::parse_event_t ev, json& parsed) {
    return tracker.event(depth, ev, parsed);
  };
  try {
    return json::parse(text, cb);
  } catch (const json::parse_error& e) {
    // "parse error at line L, column C: detail": the position goes in `where`.
    std::string detail = detailOf(e);
    const size_t col = detail.find("column ");
    const size_t sep = detail.find(": ", col == std::string::npos ? 0 : col);
    if (sep != std::string::npos) detail = detail.substr(sep + 2);
    const size_t offset = e.byte > 0 ? e.byte - 1 : 0;
    throw JsonTextError(JsonTextError::Kind::Syntax, tracker.path(), lineColumn(text, offset), detail);
  } catch (const json::out_of_range& e) {
    // A number beyond double (1e999): the value the current key was about to get.
    std::string detail = detailOf(e);
    std::string where;
    const size_t q1 = detail.find('\''), q2 = detail.rfind('\'');
    std::string token;
    if (q1 != std::string::npos && q2 > q1) token = detail.substr(q1 + 1, q2 - q1 - 1);
    if (!token.empty()) {
      const size_t pos = text.find(token);
      if (pos != std::string::npos) where = lineColumn(text, pos);
    }
    const std::string path = tracker.path();
    throw JsonTextError(JsonTextError::Kind::NumberOutOfRange, path, where,
                        (path.empty() ? std::string("a number") : "\"" + path + "\"") + " is out of range: " +
                            (token.empty() ? detail : token + " does not fit in a double"));
  } catch (const json::exception& e) {
    throw JsonTextError(JsonTextError::Kind::Syntax, tracker.path(), "", detailOf(e));
  }
}

}  // namespace fc
