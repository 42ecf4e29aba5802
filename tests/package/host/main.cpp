#include <anisocap/anisocap.hpp>

#include <cmath>
#include <cstdio>

int main() {
  anisocap::material_maps maps(20, 10);
  const float texel[anisocap::parameter_count] = {0.5f, 0.4f, 0.3f, 0.2f, 0.2f, 0.2f, 0.2f, 0.3f, 0.5f, 0.0f, 0.0f, 0.1f};
  maps.fill(texel);
  const anisocap::capture cap = anisocap::set_alpha(4, 1, 20, 10);
  const auto images = anisocap::render(maps, cap);
  const float v = images[0].at(0, 3, 4);
  std::printf("host: rendered %zu images, pixel %g\n", images.size(), double(v));
  return images.size() == 4 && std::isfinite(v) && v > 0 ? 0 : 1;
}
