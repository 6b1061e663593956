#pragma once
// Client-supplied bytes in messages: JSON and flatbuffers strings must be
// valid UTF-8, and an error echoing a path, header or name must never be
// the thing that fails.
#include <cstddef>
#include <string>
#include <string_view>

namespace fc {

// True if `s` is well-formed UTF-8 (no overlong forms, surrogates or code
// points above U+10FFFF).
bool isValidUtf8(std::string_view s);

// `s` as valid UTF-8 that prints on one line: well-formed characters are
// kept, every other byte and every control character becomes \xHH, and the
// result stops (with "...") before maxBytes.
std::string printable(std::string_view s, size_t maxBytes = 4096);

}  // namespace fc
