// Declared counts of OFF and PLY files against their size. Both loaders need at least one byte of
// the file per vertex, face or other element (a line each in OFF, a value each in PLY), so a count
// above the file size is always wrong, and refusing it bounds what Assimp allocates by the file size.
#include "mesh_check.h"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

namespace xi {
namespace {

namespace fs = std::filesystem;

// Headers are short; this much of the file is read to find them.
constexpr size_t kHeadBytes = 1 << 16;

std::string lower(std::string s) {
  for (char& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// Leading digits as a count, saturating where Assimp's strtoul10 would wrap to 32 bits.
std::optional<uint64_t> leading_count(const char*& c, const char* end) {
  if (c >= end || !std::isdigit(static_cast<unsigned char>(*c))) return {};
  uint64_t v = 0;
  for (; c < end && std::isdigit(static_cast<unsigned char>(*c)); ++c)
    v = v > (UINT64_MAX - 9) / 10 ? UINT64_MAX : v * 10 + uint64_t(*c - '0');
  return v;
}

// Assimp's OFF header: optional ST, C, N, 4, n prefixes, the keyword OFF (which may be left out), a
// dimension after the n prefix, then the vertex and face counts. Mirrors OFFImporter::InternReadFile.
std::optional<std::string> check_off(const std::string& head, uint64_t size) {
  const char* c = head.data();
  const char* end = c + head.size();
  auto next_token = [&] {  // blanks, line ends and '#' comment lines
    for (;;) {
      while (c < end && (*c == ' ' || *c == '\t' || *c == '\n' || *c == '\r' || *c == '\f')) ++c;
      if (c < end && *c == '#') {
        while (c < end && *c != '\n') ++c;
        continue;
      }
      return;
    }
  };
  auto take = [&](const char* word) {
    const size_t n = std::strlen(word);
    if (size_t(end - c) < n || std::memcmp(c, word, n) != 0) return false;
    c += n;
    return true;
  };
  next_token();
  take("ST"), take("C"), take("N"), take("4");
  const bool dimension = take("n");
  if (take("OFF") && dimension) {
    next_token();
    leading_count(c, end);
  }
  next_token();
  const auto vertices = leading_count(c, end);
  next_token();
  const auto faces = leading_count(c, end);
  if (!vertices || !faces || (*faces <= size && *vertices <= size - *faces)) return {};
  return "its header declares " + std::to_string(*vertices) + " vertices and " + std::to_string(*faces) +
         " faces, but the file has only " + std::to_string(size) + " bytes";
}

// PLY: "element NAME COUNT" lines up to end_header.
std::optional<std::string> check_ply(const std::string& head, uint64_t size) {
  std::istringstream lines(head);
  std::string line, declared;
  uint64_t total = 0;
  while (std::getline(lines, line)) {
    std::istringstream words(line);
    std::string keyword, name, count;
    words >> keyword;
    if (keyword == "end_header") break;
    if (keyword != "element" || !(words >> name >> count)) continue;
    const char* c = count.data();
    const auto n = leading_count(c, c + count.size());
    if (!n) continue;
    total = *n > UINT64_MAX - total ? UINT64_MAX : total + *n;
    declared += (declared.empty() ? "" : ", ") + std::to_string(*n) + " '" + name + "'";
  }
  if (total <= size) return {};
  return "its header declares " + declared + " elements, but the file has only " + std::to_string(size) + " bytes";
}

}  // namespace

std::optional<std::string> implausible_mesh_counts(const fs::path& path) {
  std::error_code ec;
  const uint64_t size = fs::file_size(path, ec);
  if (ec) return {};  // unreadable: Assimp reports it
  std::ifstream in(path, std::ios::binary);
  std::string head(std::min<uint64_t>(size, kHeadBytes), '\0');
  in.read(head.data(), std::streamsize(head.size()));
  head.resize(size_t(std::max<std::streamsize>(in.gcount(), 0)));

  // Assimp picks the loader by extension, then by content ("off" / "ply" in the first bytes).
  const std::string ext = lower(path.extension().string()), magic = lower(head.substr(0, 3));
  if (ext == ".off" || (ext != ".ply" && magic == "off")) return check_off(head, size);
  if (ext == ".ply" || magic == "ply") return check_ply(head, size);
  return {};
}

}  // namespace xi
