#include "core/text.h"

#include <algorithm>
#include <cstdint>

namespace fc {

namespace {

// Length of the well-formed UTF-8 sequence starting at s[i], 0 if there is none.
size_t sequenceLength(std::string_view s, size_t i) {
  const auto byte = [&](size_t k) { return uint8_t(s[k]); };
  const uint8_t c = byte(i);
  if (c < 0x80) return 1;
  size_t n;
  uint32_t cp;
  if (c >= 0xC2 && c <= 0xDF) n = 2, cp = c & 0x1F;
  else if (c >= 0xE0 && c <= 0xEF) n = 3, cp = c & 0x0F;
  else if (c >= 0xF0 && c <= 0xF4) n = 4, cp = c & 0x07;
  else return 0;
  if (i + n > s.size()) return 0;
  for (size_t k = 1; k < n; ++k) {
    const uint8_t t = byte(i + k);
    if ((t & 0xC0) != 0x80) return 0;
    cp = (cp << 6) | (t & 0x3F);
  }
  if ((n == 3 && cp < 0x800) || (n == 4 && (cp < 0x10000 || cp > 0x10FFFF))) return 0;
  if (cp >= 0xD800 && cp <= 0xDFFF) return 0;
  return n;
}

}  // namespace

bool isValidUtf8(std::string_view s) {
  for (size_t i = 0; i < s.size();) {
    const size_t n = sequenceLength(s, i);
    if (n == 0) return false;
    i += n;
  }
  return true;
}

std::string printable(std::string_view s, size_t maxBytes) {
  static const char* hex = "0123456789ABCDEF";
  std::string out;
  out.reserve(std::min(s.size(), maxBytes) + 8);
  for (size_t i = 0; i < s.size();) {
    const size_t n = sequenceLength(s, i);
    const uint8_t c = uint8_t(s[i]);
    const bool escape = n == 0 || c < 0x20 || c == 0x7F;
    const size_t add = escape ? 4 : n;
    if (out.size() + add > maxBytes) {
      out += "...";
      break;
    }
    if (escape) {
      out += "\\x";
      out += hex[c >> 4];
      out += hex[c & 15];
      i += 1;
    } else {
      out.append(s.substr(i, n));
      i += n;
    }
  }
  return out;
}

}  // namespace fc
