// Renders a scene through libxi and writes the mean radiance to an EXR:
//   app SCENE.json OUT.exr SIZE SPP SEED   (a SIZE×SIZE image; the other settings from the scene)
#include <cstdio>
#include <string>

#include <xi/error.h>
#include <xi/image.h>
#include <xi/renderer.h>
#include <xi/scene.h>

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: app SCENE.json OUT.exr SIZE SPP SEED\n");
    return 2;
  }
  try {
    xi::Scene scene = xi::load_scene(argv[1]);
    scene.width = scene.height = std::stoi(argv[3]);
    xi::RenderOptions options;  // as `xi render` sets them: the scene's render block, then the flags
    options.max_depth = scene.render.max_depth;
    options.sampler = xi::parse_sampler(scene.render.sampler);
    options.spp = std::stoi(argv[4]);
    options.seed = (uint32_t)std::stoul(argv[5]);

    xi::Device device = xi::Device::open();  // the first CPU device, or $XI_DEVICE
    xi::Renderer renderer(device, scene, options);
    renderer.render();
    xi::Image mean = renderer.mean();
    xi::write_exr(argv[2], {{"", &mean}});
    std::printf("device: %s\nkernels: %s\n", device.info().name.c_str(), xi::kernel_dir().c_str());
  } catch (const std::exception& e) {  // xi::Error says what and where; std::stoi throws too
    std::fprintf(stderr, "app: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
