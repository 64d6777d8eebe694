// Deterministic fuzzing of scene parsing and mesh loading (no OpenCL device). Every case must end in
// a scene (parse_scene, then compile_scene, which builds the BVH) or in one xi::Error with a one-line
// message. Anything else (another exception, a crash, a sanitizer report, a hang, a scene that breaks
// the loader's own guarantees) is a failure that prints the case: its label, what was mutated and
// the scene text, so that `xi_fuzz --seed S --case I` replays it.
//
// Cases: first every file of Assimp's invalid-model corpus as the one shape of a small scene (a
// "mesh", then an "asset"), then --cases mutations of the bundled scenes (scenes/, bench/scenes/,
// tests/data/scenes/): byte flips, truncation, inserted and deleted bytes, deleted and duplicated
// keys, values of another type, extreme numbers, odd mesh files, textures and environment maps
// (good, damaged, of the wrong kind), lights with odd fields. Case I depends only on (seed, I).
//
//   xi_fuzz [--cases N] [--seed S] [--case I] [--timeout SECONDS] [--verbose]
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <typeinfo>
#include <vector>

#include <nlohmann/json.hpp>

#include "xi/compiled_scene.h"
#include "xi/error.h"
#include "xi/scene.h"

#if defined(__SANITIZE_ADDRESS__)
#define XI_FUZZ_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define XI_FUZZ_ASAN 1
#endif
#endif
// Sanitizer reports abort, so that the SIGABRT handler below names the case (GCC's UBSan runtime is
// separate from ASan's and has no death callback of its own). A memory blow-up must end in such a
// report, not in the kernel's OOM killer. ASAN_OPTIONS and UBSAN_OPTIONS still override these.
extern "C" const char* __asan_default_options() {
  return "abort_on_error=1:max_allocation_size_mb=2048:hard_rss_limit_mb=4096";
}
extern "C" const char* __ubsan_default_options() { return "abort_on_error=1:print_stacktrace=1"; }

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

// ---------------------------------------------------------------------------------------------
// Reporting: the case being run, written out by whatever ends the process.

std::string g_report;  // the current case, ready to print

void write_report(const char* why) {
  // Only write(2): this runs in signal handlers and sanitizer death callbacks.
  const char head[] = "\nxi_fuzz: FAIL ";
  [[maybe_unused]] ssize_t r = ::write(2, head, sizeof head - 1);
  r = ::write(2, why, std::strlen(why));
  r = ::write(2, ": ", 2);
  r = ::write(2, g_report.data(), g_report.size());
}

void on_signal(int sig) {
  write_report(sig == SIGALRM ? "(hang: the case ran past --timeout)"
               : sig == SIGABRT ? "(aborted: see the sanitizer report or message above)"
                                : strsignal(sig));
  if (sig == SIGALRM) _exit(1);
  std::signal(sig, SIG_DFL);
  std::raise(sig);
}

// Non-printable bytes as \xHH, so that the text can be read and pasted back.
std::string printable(const std::string& s) {
  std::string out;
  for (unsigned char c : s) {
    if (c == '\n' || (c >= 0x20 && c < 0x7f)) {
      out += char(c);
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", c);
      out += buf;
    }
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Randomness: splitmix64, the same stream on every platform and standard library.

struct Rng {
  uint64_t s;
  uint64_t next() {
    uint64_t z = (s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  size_t below(size_t n) { return n ? size_t(next() % n) : 0; }
  bool percent(size_t p) { return below(100) < p; }
  template <class T>
  const T& pick(const std::vector<T>& v) { return v[below(v.size())]; }
};

// ---------------------------------------------------------------------------------------------
// Inputs

struct Base {
  std::string name;  // relative to the repository, for messages
  std::string text;
  json doc;
  fs::path dir;      // mesh paths are relative to it
  double weight = 1.0;
};

// How often a base is drawn: a case costs about its triangle count (icosphere, mesh loading, BVH),
// and the scenes of a million triangles would otherwise take nearly all the time. Estimated from the
// text (a sphere is 20 * 4^subdivisions, a mesh file about one triangle per 16 bytes).
double weight_of(const Base& b) {
  double n = 0.0;
  const json shapes = b.doc.value("shapes", json::array());
  for (const json& s : shapes) {
    const std::string type = s.value("type", "");
    if (type == "quad" || type == "triangle") {
      n += 2.0;
    } else if (type == "sphere") {
      n += 20.0 * std::pow(4.0, s.value("subdivisions", 4));
    } else if (type == "mesh") {
      std::error_code ec;
      const auto bytes = fs::file_size(b.dir / s.value("file", ""), ec);
      n += ec ? 0.0 : double(bytes) / 16.0;
    }
  }
  return std::min(1.0, 1024.0 / std::max(n, 1.0));
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Numbers at and beyond the edges of float, double and the integer types, signed zero, negative
// sizes; written into the text as they are (1e400 is not even a double).
const std::vector<std::string> kLiterals = {
    "1e39", "-1e39", "1e308", "-1e308", "1e400", "-1e400", "3.4028234e38", "-3.4028234e38", "3e38", "1e30",
    "1e-45", "5e-324", "-0", "-0.0", "0", "1", "-1", "-512", "0.5", "3", "9", "65", "16384", "16385",
    "2147483647", "2147483648", "-2147483648", "-2147483649", "4294967296", "9223372036854775807",
    "9223372036854775808", "-9223372036854775808", "-9223372036854775809", "18446744073709551615",
    "18446744073709551616", "123456789012345678901234567890"};

// Keys whose values are sizes, counts and other ranges worth hitting directly.
const std::vector<std::string> kSettings = {
    "/film/width", "/film/height", "/render/spp", "/render/max_depth", "/render/seed", "/camera/fov",
    "/camera/aperture_radius", "/camera/focus_distance", "/camera/focal_length_mm", "/camera/film_height_mm"};
const std::vector<std::string> kShapeSettings = {"radius", "subdivisions", "transform/scale", "transform/rotate/degrees",
                                                 "center/0", "vertices/0/1"};

// Values of every JSON type, to put where another type is expected.
std::vector<json> other_values() {
  return {nullptr, true, false, "", "text", 0, -1, 1.5, json::array(), json::object(), json::array({1, 2, 3}),
          json::array({json::array({0, 0, 0}), json::array({1, 0, 0}), json::array({0, 1, 0})}),
          json{{"type", "diffuse"}}, "../../../etc/passwd"};
}

// Mesh files a scene may point at: missing, empty names, folders, devices, files of the wrong
// format, absurd names, and the invalid corpus.
std::vector<std::string> odd_files(const std::vector<fs::path>& corpus, const std::string& root) {
  std::vector<std::string> v = {"missing.obj", "", ".", "..", "/", "/dev/null", "/dev/zero", "/proc/self/status",
                                root + "/README.md", root + "/docs/cornell-box.png", root + "/scenes/cornell-box.json",
                                root + "/tests/data/scenes/flat-sphere.obj", "/usr/share/assimp/models/OFF/invalid.off",
                                std::string("nul\0byte.obj", 12), std::string(5000, 'x') + ".obj", "meshes/../../../x.ply",
                                "no-extension", "UPPER.OBJ"};
  for (const auto& p : corpus) v.push_back(p.string());
  return v;
}

// Images a texture or an environment may name: good ones, and damaged copies of a PNG and of the
// bundled sky written into `dir` (cut short, bytes flipped, a header claiming a huge size, empty,
// text named .png), an 8-bit image as an environment, a folder, a missing file; and glTF models
// with textures, as asset shapes.
std::vector<std::string> image_files(const std::string& root, const fs::path& dir) {
  const std::string png = "/usr/share/assimp/models/glTF2/BoxTextured-glTF/CesiumLogoFlat.png";
  const std::string sky = root + "/scenes/sky.hdr";
  fs::create_directories(dir);
  auto write = [&](const std::string& name, const std::string& bytes) {
    std::ofstream(dir / name, std::ios::binary) << bytes;
    return (dir / name).string();
  };
  const std::string p = read_file(png), h = read_file(sky);
  std::string flipped = p, huge = p, hdr_flipped = h;
  for (size_t at = 64; at < flipped.size(); at += 97) flipped[at] = char(flipped[at] ^ 0x5a);
  for (size_t at = 200; at < hdr_flipped.size(); at += 61) hdr_flipped[at] = char(hdr_flipped[at] ^ 0xff);
  if (huge.size() > 24) huge.replace(16, 8, std::string("\x7f\xff\xff\xff\x7f\xff\xff\xff", 8));  // IHDR width, height
  std::string hdr_header = h.substr(0, std::min<size_t>(h.size(), h.find("\n\n") + 2));
  return {png, sky, root + "/docs/cornell-box.png", "missing.png", "", dir.string(),
          write("half.png", p.substr(0, p.size() / 2)), write("flipped.png", flipped), write("huge.png", huge),
          write("empty.png", ""), write("text.png", "not an image\n"), write("half.hdr", h.substr(0, h.size() / 3)),
          write("flipped.hdr", hdr_flipped), write("header-only.hdr", hdr_header + "-Y 4 +X 4\n"),
          write("fake.exr", "v/1\x01 not an exr"),
          "/usr/share/assimp/models/glTF2/BoxTextured-glTF/BoxTextured.gltf",
          "/usr/share/assimp/models/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb",
          "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf",
          "/usr/share/assimp/models/glTF2/ClearCoat-glTF/ClearCoatTest.gltf"};
}

// Every node of a document, as JSON pointers (the root included).
void collect(const json& j, const json::json_pointer& at, std::vector<json::json_pointer>& out) {
  out.push_back(at);
  if (j.is_object())
    for (const auto& item : j.items()) collect(item.value(), at / item.key(), out);
  else if (j.is_array())
    for (size_t i = 0; i < j.size(); ++i) collect(j[i], at / i, out);
}

struct Case {
  std::string label;  // "seed S case I" or "corpus FILE"
  std::string base;   // the scene it came from
  std::string what;   // the mutations, in order
  std::string text;   // the scene text to parse
  fs::path dir;
};

// Markers put into the document and replaced in its text, for what a document cannot hold: a
// literal number exactly as written, a duplicated key.
const std::string kLiteralMarker = "@@xi_fuzz_literal_", kKeyMarker = "@@xi_fuzz_key_";

struct Mutator {
  Rng rng;
  json doc;
  std::vector<std::pair<std::string, std::string>> replace;  // marker string → text
  std::string what;

  void note(const std::string& s) { what += (what.empty() ? "" : "; ") + s; }

  std::string literal_marker(const std::string& literal) {
    const std::string m = kLiteralMarker + std::to_string(replace.size()) + "@@";
    replace.emplace_back(json(m).dump(), literal);
    return m;
  }

  std::vector<json::json_pointer> nodes(bool members_only) {
    std::vector<json::json_pointer> all, out;
    collect(doc, json::json_pointer(), all);
    for (auto& p : all)
      if (!p.empty() && (!members_only || doc.at(p.parent_pointer()).is_object())) out.push_back(p);
    return out;
  }

  void delete_key() {
    const auto members = nodes(true);
    if (members.empty()) return;
    const auto p = rng.pick(members);
    doc.at(p.parent_pointer()).erase(p.back());
    note("delete " + p.to_string());
  }
  void duplicate_key() {
    const auto members = nodes(true);
    if (members.empty()) return;
    const auto p = rng.pick(members);
    const std::string marker = kKeyMarker + std::to_string(replace.size()) + "@@";
    replace.emplace_back(json(marker).dump(), json(p.back()).dump());
    const json value = rng.percent(50) ? doc.at(p) : rng.pick(other_values());
    doc.at(p.parent_pointer())[marker] = value;
    note("duplicate " + p.to_string() + " as " + value.dump());
  }
  void swap_type() {
    const auto all = nodes(false);
    if (all.empty()) return;
    const auto p = rng.pick(all);
    json v = rng.pick(other_values());
    if (v.type() == doc.at(p).type()) v = "swapped";
    doc.at(p) = v;
    note("set " + p.to_string() + " = " + v.dump());
  }
  void extreme_number() {
    std::vector<json::json_pointer> numbers;
    for (auto& p : nodes(false))
      if (doc.at(p).is_number()) numbers.push_back(p);
    if (numbers.empty()) return;
    const auto p = rng.pick(numbers);
    const std::string lit = rng.pick(kLiterals);
    doc.at(p) = literal_marker(lit);
    note("set " + p.to_string() + " = " + lit);
  }
  void setting() {  // film, render and camera settings and shape sizes, created if absent
    std::string ptr = rng.pick(kSettings);
    if (rng.percent(40) && doc.contains("shapes") && doc["shapes"].is_array() && !doc["shapes"].empty())
      ptr = "/shapes/" + std::to_string(rng.below(doc["shapes"].size())) + "/" + rng.pick(kShapeSettings);
    const std::string lit = rng.pick(kLiterals);
    try {
      doc[json::json_pointer(ptr)] = literal_marker(lit);
      note("set " + ptr + " = " + lit);
    } catch (const json::exception&) {  // a parent is not an object or array after earlier mutations
    }
  }
  void file_reference(const std::vector<std::string>& files) {
    if (!doc.is_object()) return;
    json& shapes = doc["shapes"];
    if (!shapes.is_array()) shapes = json::array();
    const size_t i = rng.percent(70) && !shapes.empty() ? rng.below(shapes.size()) : shapes.size();
    if (i == shapes.size()) shapes.push_back(json::object());
    json& shape = shapes[i];
    if (!shape.is_object()) shape = json::object();
    const bool asset = rng.percent(30);  // an asset shape brings its own materials
    shape["type"] = asset ? "asset" : "mesh";
    shape["file"] = rng.pick(files);
    if (!shape.contains("material") && !asset) {
      const auto m = doc.find("materials");
      shape["material"] = m != doc.end() && m->is_object() && !m->empty() ? m->begin().key() : "none";
    }
    if (rng.percent(80)) {  // mostly drop the old shape's keys, so that the file itself is reached
      for (const char* k : {"vertices", "center", "radius", "subdivisions"}) shape.erase(k);
      if (asset) shape.erase("material");
    }
    note("shape " + std::to_string(i) + " = " + shape["type"].get<std::string>() + " " + json(shape["file"]).dump());
  }

  // A texture, environment or light: an image from `images` as a diffuse albedo or a pbr texture
  // slot (a file name or an object with odd fields), as the environment, or a light of a random
  // type with some fields set to odd values.
  void texture_reference(const std::vector<std::string>& images) {
    if (!doc.is_object()) return;
    const std::string image = rng.pick(images);
    const size_t kind = rng.below(4);
    if (kind == 0) {
      json env = {{"file", image}};
      if (rng.percent(30)) env["strength"] = rng.pick(other_values());
      if (rng.percent(30)) env["rotation"] = literal_marker(rng.pick(kLiterals));
      doc["environment"] = env;
      note("environment " + env.dump());
      return;
    }
    if (kind == 1) {
      static const std::vector<std::string> types = {"point", "spot", "directional", "sun", "area"};
      json light = {{"type", rng.pick(types)}, {"position", {0, 1, 0}}, {"direction", {0, -1, 0}}};
      static const std::vector<std::string> keys = {"intensity", "color", "inner_angle", "outer_angle",
                                                    "angular_radius", "direction", "position", "name"};
      for (size_t k = 0, n = rng.below(3); k < n; ++k)
        light[rng.pick(keys)] = rng.percent(50) ? rng.pick(other_values()) : json(literal_marker(rng.pick(kLiterals)));
      if (!doc["lights"].is_array()) doc["lights"] = json::array();
      doc["lights"].push_back(light);
      note("light " + light.dump());
      return;
    }
    json& materials = doc["materials"];
    if (!materials.is_object() || materials.empty()) materials = json{{"m", {{"type", "diffuse"}, {"albedo", {1, 1, 1}}}}};
    json& m = materials[std::next(materials.begin(), long(rng.below(materials.size()))).key()];
    json texture = image;
    if (rng.percent(40)) {
      static const std::vector<std::string> wraps = {"repeat", "clamp", "mirror", "bogus"};
      texture = {{"file", image}, {"wrap", rng.pick(wraps)}, {"texcoord", rng.below(4)}};
      if (rng.percent(50)) texture["scale"] = {literal_marker(rng.pick(kLiterals)), 1};
      if (rng.percent(30)) texture["rotation"] = rng.pick(other_values());
    }
    if (kind == 2) {
      m = {{"type", "diffuse"}, {"albedo", texture}};
    } else {
      const char* slot = xi::kTextureSlots[rng.below(XI_TEXTURE_SLOTS)].key;
      m = {{"type", "pbr"}, {slot, texture}, {"roughness", rng.below(2) ? 0.0 : 0.7}};
      if (rng.percent(30)) m["alpha_mode"] = rng.percent(50) ? "mask" : "blend";
      if (rng.percent(30)) m["transmission"] = 1;
    }
    note("material = " + m.dump());
  }

  // Byte-level damage on the final text.
  void bytes(std::string& text) {
    const size_t kind = rng.below(4);
    if (kind == 0) {
      const size_t n = 1 + rng.below(4);
      for (size_t k = 0; k < n && !text.empty(); ++k) {
        const size_t at = rng.below(text.size());
        text[at] = char(uint8_t(text[at]) ^ uint8_t(1 + rng.below(255)));
        note("flip byte " + std::to_string(at));
      }
    } else if (kind == 1) {
      const size_t at = rng.below(text.size() + 1);
      text.resize(at);
      note("truncate at " + std::to_string(at));
    } else if (kind == 2) {
      static const std::vector<std::string> pieces = {std::string(1, '\0'), "\"", "{", "}", "[", "]", ",", ":",
                                                      "\\", "\xC3\x28", "\xFF", "\xEF\xBB\xBF", "-", "e", "1e", "\\u0000"};
      const size_t at = rng.below(text.size() + 1);
      text.insert(at, rng.pick(pieces));
      note("insert at " + std::to_string(at));
    } else if (!text.empty()) {
      const size_t at = rng.below(text.size()), n = 1 + rng.below(std::min<size_t>(64, text.size() - at));
      text.erase(at, n);
      note("erase " + std::to_string(n) + " bytes at " + std::to_string(at));
    }
  }
};

// Case `index` of `seed`: a base scene and its mutations, drawn from a stream of its own.
Case mutate(const std::vector<Base>& bases, uint64_t seed, uint64_t index, const std::vector<std::string>& files,
            const std::vector<std::string>& images) {
  Rng rng{seed * 0x100000001b3ull ^ (index + 1) * 0x9e3779b97f4a7c15ull};
  double total = 0.0;
  for (const Base& b : bases) total += b.weight;
  double u = double(rng.next() >> 11) * 0x1p-53 * total;
  size_t pick = 0;
  while (pick + 1 < bases.size() && u >= bases[pick].weight) u -= bases[pick++].weight;
  const Base& base = bases[pick];
  Mutator m{rng, base.doc, {}, {}};
  std::string text = base.text;
  const size_t count = 1 + m.rng.below(3);
  bool structural = false;
  std::vector<size_t> byte_level;
  for (size_t k = 0; k < count; ++k) {
    const size_t kind = m.rng.below(9);
    if (kind < 2) {
      byte_level.push_back(k);
      continue;
    }
    structural = true;
    switch (kind) {
      case 2: m.delete_key(); break;
      case 3: m.duplicate_key(); break;
      case 4: m.swap_type(); break;
      case 5: m.extreme_number(); break;
      case 6: m.setting(); break;
      case 7: m.texture_reference(images); break;
      default: m.file_reference(m.rng.percent(20) ? images : files); break;
    }
  }
  if (structural) {
    text = m.doc.dump(m.rng.percent(50) ? 2 : -1);
    for (const auto& [marker, with] : m.replace)
      for (size_t at = text.find(marker); at != std::string::npos; at = text.find(marker, at + with.size()))
        text.replace(at, marker.size(), with);
  }
  for (size_t k = 0; k < byte_level.size(); ++k) m.bytes(text);
  return {"seed " + std::to_string(seed) + " case " + std::to_string(index), base.name, m.what, text, base.dir};
}

// A small scene whose one shape is `file`, as a mesh (with the scene's material) or as an asset.
Case corpus_case(const fs::path& file, const std::string& type) {
  json shape = {{"type", type}, {"file", file.string()}};
  if (type == "mesh") shape["material"] = "white";
  const json doc = {{"camera", {{"position", {0, 0, -5}}, {"look_at", {0, 0, 0}}, {"up", {0, 1, 0}}, {"fov", 40}}},
                    {"materials", {{"white", {{"type", "diffuse"}, {"albedo", {0.5, 0.5, 0.5}}}}}},
                    {"shapes", json::array({shape})}};
  return {"corpus " + file.string() + " as " + type, "(a one-shape scene)", type + " " + file.string(), doc.dump(2),
          file.parent_path()};
}

// ---------------------------------------------------------------------------------------------
// Running a case

struct Tally {
  size_t scenes = 0, errors = 0, failures = 0;
  std::map<std::string, size_t> kinds;  // error messages with numbers and quoted names blanked
};

std::string kind_of(const std::string& message) {
  std::string out, word;
  std::istringstream words(message);
  while (words >> word) {
    if (word.find('/') != std::string::npos) word = "<path>";
    else if (word.front() == '\'') word = "'<name>'";
    std::string digitless;  // a run of digits as one '#'
    for (char c : word)
      if (!std::isdigit(static_cast<unsigned char>(c))) digitless += c;
      else if (digitless.empty() || digitless.back() != '#') digitless += '#';
    out += (out.empty() ? "" : " ") + digitless;
  }
  return out.substr(0, 70);
}

bool finite(const glm::vec4& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z) && std::isfinite(v.w); }

// What a loaded scene must satisfy; "" if it does.
std::string check_scene(const xi::Scene& s, const xi::CompiledScene& cs) {
  if (s.width < 1 || s.height < 1 || s.width > 16384 || s.height > 16384) return "film size out of range";
  if (s.render.spp < 1 || s.render.max_depth < 1) return "spp or max depth below 1";
  if (s.triangles.empty() || cs.tri_vertices.size() != s.triangles.size()) return "triangles missing";
  for (const glm::uvec4& t : cs.tri_vertices)
    for (int k = 0; k < 3; ++k) {
      if (t[k] >= cs.vertex_count()) return "a vertex index out of range";
      if (!finite(glm::vec4(cs.vertex_position(t[k]), 0.0f))) return "a non-finite vertex coordinate";
    }
  for (const auto& v : {cs.camera.position, cs.camera.forward, cs.camera.right, cs.camera.up})
    if (!finite(v)) return "a non-finite camera vector";
  for (float x : cs.light_cdf)
    if (!std::isfinite(x)) return "a non-finite light CDF entry";
  for (float x : cs.tri_light_pdf)
    if (!std::isfinite(x)) return "a non-finite light pdf";
  return "";
}

// "" if the case ended as it must, else why not.
std::string run(const Case& c, Tally& tally) {
  try {
    const xi::Scene scene = xi::parse_scene(c.text, "fuzz.json", c.dir);
    const xi::CompiledScene compiled = xi::compile_scene(scene);
    const std::string bad = check_scene(scene, compiled);
    if (!bad.empty()) return "loaded a broken scene: " + bad;
    ++tally.scenes;
  } catch (const xi::Error& e) {
    const std::string what = e.what();
    if (e.message().empty() || what.find('\n') != std::string::npos) return "xi::Error is not one line: " + what;
    // Assimp catches std::bad_alloc itself and reports it as an error: that is still a blow-up.
    if (what.find("bad_alloc") != std::string::npos) return "ran out of memory: " + what;
    ++tally.errors;
    ++tally.kinds[kind_of(e.message())];
  } catch (const std::exception& e) {
    return std::string("exception other than xi::Error (") + typeid(e).name() + "): " + e.what();
  } catch (...) {
    return "exception of unknown type";
  }
  return "";
}

std::string describe(const Case& c) {
  return c.label + " (base " + c.base + "; " + c.what + ")\n  replay: xi_fuzz " +
         (c.label.rfind("seed ", 0) == 0 ? "--seed " + c.label.substr(5, c.label.find(' ', 5) - 5) + " --case " +
                                               c.label.substr(c.label.rfind(' ') + 1)
                                         : std::string("--cases 0")) +
         "\n  text (" + std::to_string(c.text.size()) + " bytes, other bytes as \\xHH):\n" + printable(c.text) + "\n";
}

[[noreturn]] void usage(const std::string& why) {
  std::fprintf(stderr, "xi_fuzz: %s\nusage: xi_fuzz [--cases N] [--seed S] [--case I] [--timeout SECONDS] [--verbose]\n",
               why.c_str());
  std::exit(2);
}

}  // namespace

int main(int argc, char** argv) {
  uint64_t cases = 1000, seed = 1, timeout = 120;
  int64_t only = -1;
  bool verbose = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> uint64_t {
      if (i + 1 >= argc) usage("missing value for " + a);
      char* end = nullptr;
      const uint64_t v = std::strtoull(argv[++i], &end, 10);
      if (!end || *end || argv[i][0] == '-') usage("bad value for " + a + ": " + argv[i]);
      return v;
    };
    if (a == "--cases") cases = value();
    else if (a == "--seed") seed = value();
    else if (a == "--case") only = int64_t(value());
    else if (a == "--timeout") timeout = value();
    else if (a == "--verbose") verbose = true;
    else usage("unknown argument " + a);
  }

  for (int sig : {SIGALRM, SIGABRT, SIGFPE, SIGILL})
    std::signal(sig, on_signal);
#ifndef XI_FUZZ_ASAN  // ASan reports SIGSEGV and SIGBUS itself, then aborts
  for (int sig : {SIGSEGV, SIGBUS}) std::signal(sig, on_signal);
  // A memory blow-up must end in std::bad_alloc naming the case, not in the kernel's OOM killer.
  const rlimit limit{4ull << 30, 4ull << 30};
  setrlimit(RLIMIT_AS, &limit);
#endif

  const fs::path root = XI_ROOT_DIR, corpus_dir = XI_ASSIMP_INVALID_DIR;
  std::vector<fs::path> corpus;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(corpus_dir, ec))
    if (e.is_regular_file()) corpus.push_back(e.path());
  std::sort(corpus.begin(), corpus.end());
  if (corpus.empty()) {
    std::fprintf(stderr, "xi_fuzz: no files in %s (Debian's assimp-testmodels; scripts/install-deps.sh)\n",
                 corpus_dir.c_str());
    return 1;
  }

  std::vector<Base> bases;
  for (const char* sub : {"scenes", "bench/scenes", "tests/data/scenes"}) {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(root / sub, ec))
      if (e.path().extension() == ".json") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    for (const auto& f : files) {
      Base b{fs::relative(f, root).string(), read_file(f), {}, f.parent_path()};
      b.doc = json::parse(b.text);
      b.weight = weight_of(b);
      bases.push_back(std::move(b));
    }
  }
  if (bases.empty()) usage("no scenes under " + root.string());
  const std::vector<std::string> files = odd_files(corpus, root.string());
  const fs::path image_dir = fs::temp_directory_path() / ("xi_fuzz_images_" + std::to_string(getpid()));
  const std::vector<std::string> images = image_files(root.string(), image_dir);

  Tally tally;
  auto one = [&](const Case& c) {
    g_report = describe(c);
    alarm(unsigned(timeout));
    const auto t0 = std::chrono::steady_clock::now();
    const std::string failure = run(c, tally);
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    alarm(0);
    if (!failure.empty()) {
      ++tally.failures;
      std::fprintf(stderr, "xi_fuzz: FAIL %s: %s\n", failure.c_str(), g_report.c_str());
    } else if (verbose) {
      std::printf("ok   %s, %.0f ms (%s: %s)\n", c.label.c_str(), ms, c.base.c_str(), c.what.c_str());
      std::fflush(stdout);
    }
  };

  const auto start = std::chrono::steady_clock::now();
  if (only >= 0) {
    const Case c = mutate(bases, seed, uint64_t(only), files, images);
    std::printf("%s", describe(c).c_str());
    one(c);
  } else {
    for (const auto& f : corpus)
      for (const char* type : {"mesh", "asset"}) one(corpus_case(f, type));
    for (uint64_t i = 0; i < cases; ++i) one(mutate(bases, seed, i, files, images));
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  std::printf("xi_fuzz: seed %" PRIu64 ": %zu corpus files (as mesh and as asset) + %" PRIu64
              " mutated scenes in %.1f s: %zu loaded, %zu xi::Error, %zu failed\n",
              seed, only >= 0 ? size_t(0) : corpus.size(), only >= 0 ? uint64_t(1) : cases, seconds, tally.scenes,
              tally.errors, tally.failures);
  std::vector<std::pair<size_t, std::string>> kinds;
  for (const auto& [k, n] : tally.kinds) kinds.emplace_back(n, k);
  std::sort(kinds.rbegin(), kinds.rend());
  for (size_t k = 0; k < kinds.size() && k < (verbose ? kinds.size() : 12); ++k)
    std::printf("  %6zu  %s\n", kinds[k].first, kinds[k].second.c_str());
  fs::remove_all(image_dir, ec);
  return tally.failures ? 1 : 0;
}
