// A reader for the binary PLY files of triangles that large scanned and generated meshes come as,
// beside Assimp's. Assimp's PLY reader gives every face an allocation of its own and the scene
// graph a copy of the mesh, so a 5M-triangle mesh took 3 GB and most of the load's time; this one
// reads the file once, into the mesh itself.
#pragma once
#include <filesystem>
#include <vector>

#include "xi/scene.h"

namespace xi::scene_detail {

// Appends to `out` the vertices and triangles of `path` (and their texture coordinates) as Assimp's
// PLY reader followed by mesh_triangles(mesh, 0, flip_v) gives them (positions, vertex normals,
// texture coordinates u, v), and returns true. (One difference: aiProcess_JoinIdenticalVertices,
// which xi asks of Assimp, merges vertices whose positions, normals and texture coordinates agree
// within its small tolerance, giving them one's values; here each keeps the file's own.) For any
// file outside what it reads it returns false with `out` as it was, and Assimp reads the file as
// before: ASCII PLY, faces that are not triangles, elements other than a vertex element followed by
// a face element, face properties other than the index list, vertex lists, an index out of range,
// a file shorter than its header says, or anything else unusual in the header.
bool read_binary_ply(const std::filesystem::path& path, bool flip_v, Mesh& out);

}  // namespace xi::scene_detail
