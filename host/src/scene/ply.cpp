#include "ply.h"

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <optional>
#include <sstream>
#include <string>

#include "geometry.h"

namespace xi::scene_detail {
namespace {

// A property's scalar type, as Assimp's PLY reader names them.
enum class Type : uint8_t { I8, U8, I16, U16, I32, U32, F32, F64 };

std::optional<Type> parse_type(const std::string& s) {
  if (s == "char" || s == "int8") return Type::I8;
  if (s == "uchar" || s == "uint8") return Type::U8;
  if (s == "short" || s == "int16") return Type::I16;
  if (s == "ushort" || s == "uint16") return Type::U16;
  if (s == "int" || s == "int32") return Type::I32;
  if (s == "uint" || s == "uint32") return Type::U32;
  if (s == "float" || s == "float32") return Type::F32;
  if (s == "double" || s == "float64") return Type::F64;
  return {};
}

size_t size_of(Type t) {
  switch (t) {
    case Type::I8: case Type::U8: return 1;
    case Type::I16: case Type::U16: return 2;
    case Type::I32: case Type::U32: case Type::F32: return 4;
    case Type::F64: return 8;
  }
  return 0;
}

bool is_integer(Type t) { return t != Type::F32 && t != Type::F64; }

// The value at p, of type t, in the file's byte order.
template <class T>
T load(const unsigned char* p, bool swap) {
  unsigned char b[sizeof(T)];
  std::memcpy(b, p, sizeof(T));
  if (swap)
    for (size_t i = 0; i < sizeof(T) / 2; ++i) std::swap(b[i], b[sizeof(T) - 1 - i]);
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

// As Assimp converts every property to a float: a plain cast.
float as_float(const unsigned char* p, Type t, bool swap) {
  switch (t) {
    case Type::I8: return (float)load<int8_t>(p, swap);
    case Type::U8: return (float)load<uint8_t>(p, swap);
    case Type::I16: return (float)load<int16_t>(p, swap);
    case Type::U16: return (float)load<uint16_t>(p, swap);
    case Type::I32: return (float)load<int32_t>(p, swap);
    case Type::U32: return (float)load<uint32_t>(p, swap);
    case Type::F32: return load<float>(p, swap);
    case Type::F64: return (float)load<double>(p, swap);
  }
  return 0.0f;
}

// An integer property (a list count or an index); negative values are out of any range.
int64_t as_integer(const unsigned char* p, Type t, bool swap) {
  switch (t) {
    case Type::I8: return load<int8_t>(p, swap);
    case Type::U8: return load<uint8_t>(p, swap);
    case Type::I16: return load<int16_t>(p, swap);
    case Type::U16: return load<uint16_t>(p, swap);
    case Type::I32: return load<int32_t>(p, swap);
    case Type::U32: return load<uint32_t>(p, swap);
    default: return -1;
  }
}

struct Property {
  std::string name;
  Type type = Type::F32;
  bool list = false;
  Type count_type = Type::U8;
  size_t offset = 0;  // in the vertex record
};

struct Element {
  std::string name;
  uint64_t count = 0;
  std::vector<Property> properties;
};

struct Header {
  bool swap = false;  // big-endian data
  size_t bytes = 0;   // the header's length, up to and including "end_header\n"
  Element vertex, face;
};

// The header, if it is one this reader takes: binary, '\n' line ends, a vertex element of scalars
// followed by a face element of one index list, nothing else but comments.
std::optional<Header> parse_header(const std::string& head) {
  const size_t end = head.find("\nend_header\n");
  if (head.compare(0, 4, "ply\n") != 0 || end == std::string::npos) return {};
  Header h;
  h.bytes = end + std::strlen("\nend_header\n");
  if (head.find('\r') < h.bytes) return {};
  std::istringstream lines(head.substr(4, end - 4));
  std::string line;
  std::vector<Element> elements;
  bool format = false;
  while (std::getline(lines, line)) {
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "comment" || keyword == "obj_info") continue;
    std::vector<std::string> w;
    for (std::string s; words >> s;) w.push_back(s);
    if (keyword == "format" && !format && w.size() == 2 && w[1] == "1.0" &&
        (w[0] == "binary_little_endian" || w[0] == "binary_big_endian")) {
      format = true;
      h.swap = (w[0] == "binary_big_endian") != (std::endian::native == std::endian::big);
    } else if (keyword == "element" && format && w.size() == 2 && !w[1].empty() &&
               w[1].find_first_not_of("0123456789") == std::string::npos && w[1].size() < 19) {
      elements.push_back(Element{w[0], std::stoull(w[1]), {}});
    } else if (keyword == "property" && !elements.empty() && w.size() == 2 && parse_type(w[0])) {
      elements.back().properties.push_back(Property{w[1], *parse_type(w[0])});
    } else if (keyword == "property" && !elements.empty() && w.size() == 4 && w[0] == "list" && parse_type(w[1]) &&
               parse_type(w[2])) {
      elements.back().properties.push_back(Property{w[3], *parse_type(w[2]), true, *parse_type(w[1])});
    } else {
      return {};
    }
  }
  if (elements.size() != 2 || elements[0].name != "vertex" || elements[1].name != "face") return {};
  h.vertex = elements[0], h.face = elements[1];
  const std::vector<Property>& f = h.face.properties;
  if (f.size() != 1 || !f[0].list || (f[0].name != "vertex_indices" && f[0].name != "vertex_index") ||
      !is_integer(f[0].type) || !is_integer(f[0].count_type))
    return {};
  size_t offset = 0;
  for (Property& p : h.vertex.properties) {
    // Lists, and names Assimp gives a meaning on faces, are left to it.
    if (p.list || p.name == "vertex_indices" || p.name == "vertex_index" || p.name == "texcoord" ||
        p.name == "material_index")
      return {};
    p.offset = offset;
    offset += size_of(p.type);
  }
  return h;
}

// Which vertex property holds each value xi reads: position, normal, texture coordinates. Assimp's
// names (PlyParser.cpp): u also as s, tx or texture_u, v as t, ty or texture_v.
struct Layout {
  const Property* pos[3] = {};
  const Property* normal[3] = {};
  const Property* uv[2] = {};
  size_t stride = 0;
};

std::optional<Layout> layout(const Element& vertex) {
  Layout l;
  auto take = [](const Property*& slot, const Property& p) {
    if (slot) return false;  // two properties of one meaning: Assimp's choice
    slot = &p;
    return true;
  };
  for (const Property& p : vertex.properties) {
    const std::string& n = p.name;
    bool ok = true;
    if (n == "x") ok = take(l.pos[0], p);
    else if (n == "y") ok = take(l.pos[1], p);
    else if (n == "z") ok = take(l.pos[2], p);
    else if (n == "nx") ok = take(l.normal[0], p);
    else if (n == "ny") ok = take(l.normal[1], p);
    else if (n == "nz") ok = take(l.normal[2], p);
    else if (n == "u" || n == "s" || n == "tx" || n == "texture_u") ok = take(l.uv[0], p);
    else if (n == "v" || n == "t" || n == "ty" || n == "texture_v") ok = take(l.uv[1], p);
    if (!ok) return {};
    l.stride += size_of(p.type);
  }
  // A position needs all three; normals and texture coordinates all or none (else Assimp's choice).
  if (!l.pos[0] || !l.pos[1] || !l.pos[2]) return {};
  if (!l.normal[0] != !l.normal[1] || !l.normal[0] != !l.normal[2] || !l.uv[0] != !l.uv[1]) return {};
  return l;
}

// Reads the file in blocks: next(n) gives the next n bytes (n ≤ kBlock), or null at the end.
class Reader {
 public:
  static constexpr size_t kBlock = 1 << 20;
  Reader(std::FILE* f, size_t skip) : f_(f), buf_(new unsigned char[2 * kBlock]) {
    std::fseek(f_, (long)skip, SEEK_SET);
  }
  const unsigned char* next(size_t n) {
    if (end_ - at_ < n) {
      std::memmove(buf_.get(), buf_.get() + at_, end_ - at_);
      end_ -= at_, at_ = 0;
      end_ += std::fread(buf_.get() + end_, 1, 2 * kBlock - end_, f_);
      if (end_ < n) return nullptr;
    }
    const unsigned char* p = buf_.get() + at_;
    at_ += n;
    return p;
  }

 private:
  std::FILE* f_;
  std::unique_ptr<unsigned char[]> buf_;
  size_t at_ = 0, end_ = 0;
};

struct File {
  std::FILE* f;
  ~File() {
    if (f) std::fclose(f);
  }
};

}  // namespace

bool read_binary_ply(const std::filesystem::path& path, bool flip_v, Mesh& out) {
  File file{std::fopen(path.c_str(), "rb")};
  if (!file.f) return false;
  std::string head(1 << 16, '\0');
  head.resize(std::fread(head.data(), 1, head.size(), file.f));
  const std::optional<Header> h = parse_header(head);
  if (!h) return false;
  const std::optional<Layout> l = layout(h->vertex);
  if (!l) return false;
  const Property& list = h->face.properties[0];
  const size_t face_bytes = size_of(list.count_type) + 3 * size_of(list.type);
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  const uint64_t nv = h->vertex.count, nf = h->face.count;
  // Triangles only: the file must hold exactly what the counts say (so nothing is allocated for a
  // header that lies), or Assimp reads it.
  if (ec || nf == 0 || nv > size || nf > size || l->stride > Reader::kBlock ||
      h->bytes + nv * l->stride + nf * face_bytes > size || out.vertices.size() + nv > UINT32_MAX)
    return false;

  // The vertices straight into the mesh; texture coordinates aside, for the triangles' own entries.
  const bool normals = l->normal[0] != nullptr, uvs = l->uv[0] != nullptr;
  const size_t first_vertex = out.vertices.size(), first = out.triangles.size(), first_texcoords = out.texcoords.size();
  auto undo = [&] {
    out.vertices.resize(first_vertex), out.triangles.resize(first), out.texcoords.resize(first_texcoords);
    return false;
  };
  make_room(out.vertices, nv);
  std::vector<glm::vec2> uv(uvs ? nv : 0);
  Reader in(file.f, h->bytes);
  for (uint64_t i = 0; i < nv; ++i) {
    const unsigned char* r = in.next(l->stride);
    if (!r) return undo();
    auto get = [&](const Property* p) { return as_float(r + p->offset, p->type, h->swap); };
    Vertex& v = out.vertices.emplace_back();
    v.position = {get(l->pos[0]), get(l->pos[1]), get(l->pos[2])};
    if (normals) v.normal = {get(l->normal[0]), get(l->normal[1]), get(l->normal[2])};
    if (uvs) uv[i] = {get(l->uv[0]), get(l->uv[1])};
  }

  make_room(out.triangles, nf);
  if (uvs) make_room(out.texcoords, nf);
  const size_t count_bytes = size_of(list.count_type), index_bytes = size_of(list.type);
  for (uint64_t f = 0; f < nf; ++f) {
    const unsigned char* r = in.next(face_bytes);
    uint32_t idx[3];
    bool ok = r && as_integer(r, list.count_type, h->swap) == 3;
    for (int k = 0; ok && k < 3; ++k) {
      const int64_t i = as_integer(r + count_bytes + k * index_bytes, list.type, h->swap);
      ok = i >= 0 && (uint64_t)i < nv;
      idx[k] = (uint32_t)i;
    }
    if (!ok) return undo();  // a polygon, a bad index or a short file: Assimp's
    Triangle& t = out.triangles.emplace_back();
    t.has_normals = normals;
    TriangleTexcoords* tc = nullptr;
    if (uvs) t.texcoords = uint32_t(out.texcoords.size()), tc = &out.texcoords.emplace_back();
    for (int k = 0; k < 3; ++k) {
      t.v[k] = uint32_t(first_vertex + idx[k]);
      if (uvs) tc->uv[0][k] = {uv[idx[k]].x, flip_v ? 1.0f - uv[idx[k]].y : uv[idx[k]].y};
    }
  }
  return true;
}

}  // namespace xi::scene_detail
