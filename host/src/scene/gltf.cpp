#include "gltf.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>

#include "geometry.h"
#include "xi/error.h"
#include "xi/texture.h"

namespace xi::scene_detail {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const json* member(const json& j, const char* key) {
  return j.is_object() && j.contains(key) ? &j[key] : nullptr;
}
double number(const json& j, const char* key, double def) {
  const json* v = member(j, key);
  return v && v->is_number() && std::isfinite(v->get<double>()) ? v->get<double>() : def;
}
int index_of(const json& j, const char* key) {
  const json* v = member(j, key);
  return v && v->is_number_integer() && v->get<long long>() >= 0 && v->get<long long>() < (1LL << 30)
             ? int(v->get<long long>())
             : -1;
}
std::vector<double> numbers(const json& j, const char* key, std::vector<double> def) {
  const json* v = member(j, key);
  if (!v || !v->is_array() || v->size() != def.size()) return def;
  for (size_t i = 0; i < def.size(); ++i)
    if ((*v)[i].is_number() && std::isfinite((*v)[i].get<double>())) def[i] = (*v)[i].get<double>();
  return def;
}
const json* extension(const json& j, const char* name) {
  const json* e = member(j, "extensions");
  return e ? member(*e, name) : nullptr;
}

std::vector<uint8_t> base64_decode(const std::string& s, size_t from) {
  auto value = [](char c) -> int {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    if (c == '+' || c == '-') return 62;
    if (c == '/' || c == '_') return 63;
    return -1;
  };
  std::vector<uint8_t> out;
  uint32_t acc = 0;
  int bits = 0;
  for (size_t i = from; i < s.size() && s[i] != '='; ++i) {
    const int v = value(s[i]);
    if (v < 0) throw Error("data URI is not base64");
    acc = (acc << 6) | uint32_t(v);
    bits += 6;
    if (bits >= 8) out.push_back(uint8_t(acc >> (bits -= 8)));
  }
  return out;
}

// A URI relative to the file: percent-escapes decoded.
fs::path resolve_uri(const fs::path& file, const std::string& uri) {
  std::string s;
  for (size_t i = 0; i < uri.size(); ++i) {
    if (uri[i] == '%' && i + 2 < uri.size() && std::isxdigit((unsigned char)uri[i + 1]) &&
        std::isxdigit((unsigned char)uri[i + 2])) {
      s += char(std::stoi(uri.substr(i + 1, 2), nullptr, 16));
      i += 2;
    } else {
      s += uri[i];
    }
  }
  return file.parent_path() / s;
}

std::vector<uint8_t> read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  if (!in || !fs::is_regular_file(path, ec)) throw Error("file not found", path.string());
  return std::vector<uint8_t>((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

std::vector<uint8_t> uri_bytes(const fs::path& file, const std::string& uri) {
  if (uri.rfind("data:", 0) == 0) {
    const size_t comma = uri.find(',');
    if (comma == std::string::npos || uri.find(";base64", 0) > comma) throw Error("data URI is not base64");
    return base64_decode(uri, comma + 1);
  }
  return read_bytes(resolve_uri(file, uri));
}

class Reader {
 public:
  Reader(const GltfFile& f, Warnings& w) : file_(f), warn_(w) {}

  Material material(const json& m, size_t index) {
    Material out;
    out.name = member(m, "name") && m["name"].is_string() ? m["name"].get<std::string>() : "material " + std::to_string(index);
    out.type = MaterialType::Pbr;
    const json none = json::object();
    const json* pbr = member(m, "pbrMetallicRoughness");
    const json& p = pbr ? *pbr : none;
    const auto base = numbers(p, "baseColorFactor", {1, 1, 1, 1});
    out.albedo = glm::clamp(glm::vec3(base[0], base[1], base[2]), 0.0f, 1.0f);
    out.alpha = std::clamp(float(base[3]), 0.0f, 1.0f);
    out.metallic = std::clamp(float(number(p, "metallicFactor", 1.0)), 0.0f, 1.0f);
    out.roughness = std::clamp(float(number(p, "roughnessFactor", 1.0)), 0.0f, 1.0f);
    // Slot k from glTF's texture info `key` in `parent`.
    auto read_slot = [&](int k, const json& parent, const char* key) {
      out.textures[k] = texture(member(parent, key), kTextureSlots[k].srgb, out.name);
    };
    read_slot(XI_TEXTURE_BASE_COLOR, p, "baseColorTexture");
    read_slot(XI_TEXTURE_METALLIC_ROUGHNESS, p, "metallicRoughnessTexture");
    read_slot(XI_TEXTURE_NORMAL, m, "normalTexture");
    if (out.textures[XI_TEXTURE_NORMAL].used()) out.normal_scale = float(number(m["normalTexture"], "scale", 1.0));
    read_slot(XI_TEXTURE_EMISSIVE, m, "emissiveTexture");
    if (member(m, "occlusionTexture"))
      warn_.add("occlusionTexture is not used: the path tracer computes occlusion itself");

    const auto emissive = numbers(m, "emissiveFactor", {0, 0, 0});
    float strength = 1.0f;
    if (const json* e = extension(m, "KHR_materials_emissive_strength"))
      strength = float(std::max(0.0, number(*e, "emissiveStrength", 1.0)));
    out.emission = glm::max(glm::vec3(emissive[0], emissive[1], emissive[2]), 0.0f) * strength;
    if (!std::isfinite(out.emission.x + out.emission.y + out.emission.z))
      throw Error("material '" + out.name + "' has a non-finite emissive factor x strength", file_.path.string());
    out.two_sided = member(m, "doubleSided") && m["doubleSided"].is_boolean() && m["doubleSided"].get<bool>();

    if (const json* e = extension(m, "KHR_materials_ior")) out.ior = std::clamp(float(number(*e, "ior", 1.5)), 1.0f, 4.0f);
    if (const json* e = extension(m, "KHR_materials_transmission")) {
      out.transmission = std::clamp(float(number(*e, "transmissionFactor", 0.0)), 0.0f, 1.0f);
      if (member(*e, "transmissionTexture"))
        warn_.add("transmissionTexture is not modelled: its materials use their transmission factor");
    }

    if (const json* e = extension(m, "KHR_materials_specular")) {
      out.specular = std::clamp(float(number(*e, "specularFactor", 1.0)), 0.0f, 1.0f);
      const auto colour = numbers(*e, "specularColorFactor", {1, 1, 1});
      out.specular_color = glm::clamp(glm::vec3(colour[0], colour[1], colour[2]), 0.0f, 1e3f);
      read_slot(XI_TEXTURE_SPECULAR, *e, "specularTexture");
      read_slot(XI_TEXTURE_SPECULAR_COLOR, *e, "specularColorTexture");
    }
    if (const json* e = extension(m, "KHR_materials_volume")) {
      // A thickness of 0 makes the surface thin-walled: no volume inside.
      if (number(*e, "thicknessFactor", 0.0) > 0.0) {
        const auto colour = numbers(*e, "attenuationColor", {1, 1, 1});
        out.attenuation_color = glm::clamp(glm::vec3(colour[0], colour[1], colour[2]), 0.0f, 1.0f);
        const double distance = number(*e, "attenuationDistance", std::numeric_limits<double>::infinity());
        if (distance > 0.0) out.attenuation_distance = float(distance);
      }
    }
    if (const json* e = extension(m, "KHR_materials_sheen")) {
      const auto colour = numbers(*e, "sheenColorFactor", {0, 0, 0});
      out.sheen_color = glm::clamp(glm::vec3(colour[0], colour[1], colour[2]), 0.0f, 1.0f);
      out.sheen_roughness = std::clamp(float(number(*e, "sheenRoughnessFactor", 0.0)), 0.0f, 1.0f);
      read_slot(XI_TEXTURE_SHEEN_COLOR, *e, "sheenColorTexture");
      read_slot(XI_TEXTURE_SHEEN_ROUGHNESS, *e, "sheenRoughnessTexture");
    }
    if (const json* e = extension(m, "KHR_materials_clearcoat")) {
      out.clearcoat = std::clamp(float(number(*e, "clearcoatFactor", 0.0)), 0.0f, 1.0f);
      out.clearcoat_roughness = std::clamp(float(number(*e, "clearcoatRoughnessFactor", 0.0)), 0.0f, 1.0f);
      read_slot(XI_TEXTURE_CLEARCOAT, *e, "clearcoatTexture");
      read_slot(XI_TEXTURE_CLEARCOAT_ROUGHNESS, *e, "clearcoatRoughnessTexture");
      read_slot(XI_TEXTURE_CLEARCOAT_NORMAL, *e, "clearcoatNormalTexture");
      if (out.textures[XI_TEXTURE_CLEARCOAT_NORMAL].used())
        out.clearcoat_normal_scale = float(number(*member(*e, "clearcoatNormalTexture"), "scale", 1.0));
    }

    if (const json* e = extension(m, "KHR_materials_anisotropy")) {
      out.anisotropy_strength = std::clamp(float(number(*e, "anisotropyStrength", 0.0)), 0.0f, 1.0f);
      out.anisotropy_rotation = float(number(*e, "anisotropyRotation", 0.0));
      if (!std::isfinite(out.anisotropy_rotation))
        throw Error("material '" + out.name + "' has a non-finite anisotropy rotation", file_.path.string());
      read_slot(XI_TEXTURE_ANISOTROPY, *e, "anisotropyTexture");
    }
    if (const json* e = extension(m, "KHR_materials_iridescence")) {
      out.iridescence = std::clamp(float(number(*e, "iridescenceFactor", 0.0)), 0.0f, 1.0f);
      out.iridescence_ior = std::clamp(float(number(*e, "iridescenceIor", 1.3)), 1.0f, 4.0f);
      out.iridescence_thickness_minimum = std::clamp(float(number(*e, "iridescenceThicknessMinimum", 100.0)), 0.0f, 1e5f);
      out.iridescence_thickness_maximum = std::clamp(float(number(*e, "iridescenceThicknessMaximum", 400.0)), 0.0f, 1e5f);
      read_slot(XI_TEXTURE_IRIDESCENCE, *e, "iridescenceTexture");
      read_slot(XI_TEXTURE_IRIDESCENCE_THICKNESS, *e, "iridescenceThicknessTexture");
    }

    const std::string mode = member(m, "alphaMode") && m["alphaMode"].is_string() ? m["alphaMode"].get<std::string>() : "OPAQUE";
    out.alpha_mode = mode == "MASK" ? AlphaMode::Mask : mode == "BLEND" ? AlphaMode::Blend : AlphaMode::Opaque;
    out.alpha_cutoff = float(number(m, "alphaCutoff", 0.5));

    static const std::map<std::string, std::string> unmodelled = {
        {"KHR_materials_unlit", "unlit materials are not modelled: rendered as lit metallic-roughness"},
        {"KHR_materials_dispersion", "dispersion needs spectral rendering, which xi does not do: one ior for every wavelength"},
        {"KHR_materials_diffuse_transmission", "diffuse transmission is not modelled: the surface is opaque"},
    };
    if (const json* e = member(m, "extensions"); e && e->is_object())
      for (const auto& item : e->items()) {
        const auto found = unmodelled.find(item.key());
        if (found != unmodelled.end()) warn_.add(found->second);
      }
    // Specular-glossiness, preferred to the metallic-roughness fallback beside it (as the extension
    // asks, and Blender's importer does): the diffuse colour under a dielectric layer whose F0 is
    // the specular colour (KHR_materials_specular's tint over the ior's f0), roughness 1 − glossiness.
    if (const json* sg = extension(m, "KHR_materials_pbrSpecularGlossiness")) {
      const auto diffuse = numbers(*sg, "diffuseFactor", {1, 1, 1, 1});
      out.albedo = glm::clamp(glm::vec3(diffuse[0], diffuse[1], diffuse[2]), 0.0f, 1.0f);
      out.alpha = std::clamp(float(diffuse[3]), 0.0f, 1.0f);
      out.metallic = 0.0f;
      out.roughness = std::clamp(1.0f - float(number(*sg, "glossinessFactor", 1.0)), 0.0f, 1.0f);
      const auto specular = numbers(*sg, "specularFactor", {1, 1, 1});
      const float q = (out.ior - 1.0f) / (out.ior + 1.0f), f0 = q * q;
      out.specular = 1.0f;
      out.specular_color = glm::clamp(glm::vec3(specular[0], specular[1], specular[2]), 0.0f, 1.0f) / f0;
      out.textures[XI_TEXTURE_METALLIC_ROUGHNESS] = {};
      read_slot(XI_TEXTURE_BASE_COLOR, *sg, "diffuseTexture");
      if (member(*sg, "specularGlossinessTexture"))
        warn_.add("specularGlossinessTexture is not modelled: specular-glossiness materials use their factors");
    }
    return out;
  }

  std::vector<TextureImage> take_images() { return std::move(images_); }

 private:
  // A textureInfo: its image (decoded once per colour or data use), coordinates, wrap and transform.
  TextureSlot texture(const json* info, bool srgb, const std::string& material) {
    TextureSlot slot;
    if (!info) return slot;
    const std::string what = "material '" + material + "': ";
    const int tex = index_of(*info, "index");
    const json* textures = member(file_.doc, "textures");
    if (tex < 0 || !textures || !textures->is_array() || size_t(tex) >= textures->size()) {
      warn_.add(what + "a texture index out of range: the texture is ignored");
      return slot;
    }
    const json& t = (*textures)[tex];
    int source = index_of(t, "source");
    if (source < 0) {
      warn_.add(what + "a texture with no image xi decodes (e.g. KTX2 or WebP only): the texture is ignored");
      return slot;
    }
    slot.image = image(source, srgb, what);
    if (slot.image < 0) return TextureSlot{};
    slot.texcoord = index_of(*info, "texCoord") < 0 ? 0 : index_of(*info, "texCoord");
    if (const int s = index_of(t, "sampler"); s >= 0) {
      const json* samplers = member(file_.doc, "samplers");
      if (samplers && samplers->is_array() && size_t(s) < samplers->size()) {
        auto wrap = [&](const char* key) {
          const int mode = int(number((*samplers)[s], key, 10497));
          return mode == 33071 ? Wrap::Clamp : mode == 33648 ? Wrap::Mirror : Wrap::Repeat;
        };
        slot.wrap_s = wrap("wrapS");
        slot.wrap_t = wrap("wrapT");
      }
    }
    if (const json* x = extension(*info, "KHR_texture_transform")) {
      const auto offset = numbers(*x, "offset", {0, 0}), scale = numbers(*x, "scale", {1, 1});
      slot.transform = texture_transform(glm::vec2(float(offset[0]), float(offset[1])),
                                         float(number(*x, "rotation", 0.0)), glm::vec2(float(scale[0]), float(scale[1])));
      if (index_of(*x, "texCoord") >= 0) slot.texcoord = index_of(*x, "texCoord");
    }
    if (slot.texcoord > 1) {
      warn_.add(what + "texture coordinate sets beyond 1 are not read: set 0 is used");
      slot.texcoord = 0;
    }
    return slot;
  }

  int image(int source, bool srgb, const std::string& what) {
    const auto key = std::make_pair(source, srgb);
    if (auto found = decoded_.find(key); found != decoded_.end()) return found->second;
    int result = -1;
    const std::string name = file_.path.filename().string() + ": image " + std::to_string(source);
    try {
      const json* images = member(file_.doc, "images");
      if (!images || !images->is_array() || size_t(source) >= images->size()) throw Error("image index out of range");
      const json& img = (*images)[source];
      std::vector<uint8_t> bytes;
      std::string label = name;
      if (member(img, "uri") && img["uri"].is_string()) {
        const std::string uri = img["uri"].get<std::string>();
        if (uri.rfind("data:", 0) != 0) label = resolve_uri(file_.path, uri).string();
        bytes = uri_bytes(file_.path, uri);
      } else {
        bytes = buffer_view(index_of(img, "bufferView"));
      }
      images_.push_back(decode_image(bytes, label, srgb));
      result = int(images_.size()) - 1;
    } catch (const Error& e) {
      warn_.add(what + "texture image '" + (e.where().empty() ? name : e.where()) + "' cannot be used (" + e.message() +
                "): the material uses its factors alone");
    }
    decoded_[key] = result;
    return result;
  }

  std::vector<uint8_t> buffer_view(int view) {
    const json* views = member(file_.doc, "bufferViews");
    const json* buffers = member(file_.doc, "buffers");
    if (view < 0 || !views || !views->is_array() || size_t(view) >= views->size()) throw Error("bufferView out of range");
    const json& v = (*views)[view];
    const int b = index_of(v, "buffer");
    if (b < 0 || !buffers || !buffers->is_array() || size_t(b) >= buffers->size()) throw Error("buffer out of range");
    const json& buf = (*buffers)[b];
    std::vector<uint8_t> data;
    if (member(buf, "uri") && buf["uri"].is_string())
      data = uri_bytes(file_.path, buf["uri"].get<std::string>());
    else
      data.assign(file_.bin.begin(), file_.bin.end());
    const double offset = number(v, "byteOffset", 0.0), length = number(v, "byteLength", -1.0);
    if (offset < 0 || length < 0 || offset + length > double(data.size())) throw Error("bufferView outside its buffer");
    return std::vector<uint8_t>(data.begin() + size_t(offset), data.begin() + size_t(offset + length));
  }

  const GltfFile& file_;
  Warnings& warn_;
  std::vector<TextureImage> images_;
  std::map<std::pair<int, bool>, int> decoded_;
};

}  // namespace

std::optional<GltfFile> read_gltf(const fs::path& path) {
  try {
    GltfFile f;
    f.path = path;
    std::ifstream in(path, std::ios::binary);
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (lower_extension(path) == ".glb") {  // 12-byte header, then chunks: length, type, data
      if (text.size() < 20 || text.compare(0, 4, "glTF") != 0) return std::nullopt;
      std::string json_text;
      for (size_t at = 12; at + 8 <= text.size();) {
        uint32_t length = 0, type = 0;
        std::memcpy(&length, text.data() + at, 4);
        std::memcpy(&type, text.data() + at + 4, 4);
        if (length > text.size() - at - 8) return std::nullopt;
        if (type == 0x4E4F534Au) json_text = text.substr(at + 8, length);  // "JSON"
        if (type == 0x004E4942u) f.bin = text.substr(at + 8, length);      // "BIN\0"
        at += 8 + size_t(length);
      }
      text = json_text;
    }
    f.doc = json::parse(text);
    if (!f.doc.is_object()) return std::nullopt;
    return f;
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

GltfMaterials gltf_materials(const GltfFile& file, Warnings& warn) {
  GltfMaterials out;
  Reader reader(file, warn);
  if (const json* list = member(file.doc, "materials"); list && list->is_array())
    for (size_t i = 0; i < list->size(); ++i) out.materials.push_back(reader.material((*list)[i], i));
  out.images = reader.take_images();
  return out;
}

}  // namespace xi::scene_detail
