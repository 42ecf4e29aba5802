#pragma once
// A minimal 16-bit PNG writer for tests (stb cannot write 16-bit): zlib stored blocks, CRC-32,
// Adler-32.
#include <algorithm>
#include <cstdint>
#include <vector>

namespace anisocap::testing {

namespace png16_detail {

inline std::uint32_t crc32(const unsigned char* data, std::size_t n, std::uint32_t crc = 0) {
  crc = ~crc;
  for (std::size_t i = 0; i < n; ++i) {
    crc ^= data[i];
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}
inline void put32(std::vector<unsigned char>& out, std::uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) out.push_back(static_cast<unsigned char>(v >> s));
}
inline void chunk(std::vector<unsigned char>& out, const char* type, const std::vector<unsigned char>& data) {
  put32(out, std::uint32_t(data.size()));
  std::vector<unsigned char> body(type, type + 4);
  body.insert(body.end(), data.begin(), data.end());
  out.insert(out.end(), body.begin(), body.end());
  put32(out, crc32(body.data(), body.size()));
}
}  // namespace png16_detail

/// 16-bit PNG of `channels` (1 grey, 3 RGB) interleaved samples, row by row.
inline std::vector<unsigned char> png16(int width, int height, int channels, const std::vector<std::uint16_t>& samples) {
  using namespace png16_detail;
  std::vector<unsigned char> raw;
  for (int y = 0; y < height; ++y) {
    raw.push_back(0);  // filter: none
    for (int i = 0; i < width * channels; ++i) {
      const std::uint16_t s = samples[std::size_t(y) * std::size_t(width * channels) + std::size_t(i)];
      raw.push_back(static_cast<unsigned char>(s >> 8));
      raw.push_back(static_cast<unsigned char>(s & 255));
    }
  }
  std::vector<unsigned char> z = {0x78, 0x01};
  for (std::size_t pos = 0; pos < raw.size() || pos == 0;) {
    const std::size_t n = std::min<std::size_t>(65535, raw.size() - pos);
    z.push_back(pos + n == raw.size() ? 1 : 0);  // BFINAL, BTYPE = stored
    z.push_back(static_cast<unsigned char>(n & 255));
    z.push_back(static_cast<unsigned char>(n >> 8));
    z.push_back(static_cast<unsigned char>(~n & 255));
    z.push_back(static_cast<unsigned char>((~n >> 8) & 255));
    z.insert(z.end(), raw.begin() + std::ptrdiff_t(pos), raw.begin() + std::ptrdiff_t(pos + n));
    pos += n;
    if (n == 0) break;
  }
  std::uint32_t a = 1, b = 0;
  for (unsigned char c : raw) a = (a + c) % 65521, b = (b + a) % 65521;
  put32(z, (b << 16) | a);
  std::vector<unsigned char> out = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  std::vector<unsigned char> ihdr;
  put32(ihdr, std::uint32_t(width));
  put32(ihdr, std::uint32_t(height));
  ihdr.insert(ihdr.end(), {16, static_cast<unsigned char>(channels == 3 ? 2 : 0), 0, 0, 0});
  chunk(out, "IHDR", ihdr);
  chunk(out, "IDAT", z);
  chunk(out, "IEND", {});
  return out;
}


}  // namespace anisocap::testing
