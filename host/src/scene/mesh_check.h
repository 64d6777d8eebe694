// Checks a mesh file's declared element counts before Assimp reads it. Assimp's OFF and PLY loaders
// allocate (and zero) whatever their headers declare, so a file of a few hundred bytes claiming
// billions of vertices (Assimp's own models/invalid/OutOfMemory.off) exhausts memory.
#pragma once
#include <filesystem>
#include <optional>
#include <string>

namespace xi {

// Why the file cannot be what it claims (e.g. "declares 353535235358 vertices and 6 faces in 309
// bytes"), or nothing when its counts fit its size or it is not an OFF or PLY file.
std::optional<std::string> implausible_mesh_counts(const std::filesystem::path& path);

}  // namespace xi
