// How close can a GGX lobe come to the Ward lobe it replaces in an export? For each Ward lobe
// (sigma_x, sigma_y) of a grid, the relative cosine-weighted L1 distance
//   E = int int |g D V(l, v; a_x, a_y) - W(l, v; sigma_x, sigma_y)| cos_l dl dv / int int W cos_l dl dv
// (D V: anisotropic GGX with height-correlated Smith, export/target_models.hpp; W: the Ward lobe of
// brdf/ward.hpp without Fresnel, in the same frame) of
//   - the closed form the exports use: a = k sigma on each axis, g = 1 (k = 0.9, and k = 1);
//   - the best widths: a_x, a_y fitted to minimise E, g = 1;
//   - the best widths and gain: a_x, a_y and the specular gain g fitted.
// The gap between the closed form and the best fit is what a per-texel fitted conversion can win on
// a specular-dominated texel; the best fit's E is what no GGX target can go below.
// Directions: v on a polar grid over the hemisphere (zenith to 80 degrees; by the lobe's symmetry a
// quarter of the azimuths), l the mirror of v about half vectors h on a grid in slope space that
// is dense where the Ward lobe is (s = sigma sinh t, t uniform, slopes to 6), with the Jacobian
// dl = 4 (v.h) dh and dh = cos^3(theta_h) ds_x ds_y. The fits are compass searches in log space.
//
//   anisocap_study_ggx_lobe_fit [--slopes 24] [--zeniths 8] [--azimuths 3]
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <string>
#include <vector>

#include "anisocap/brdf/ward.hpp"
#include "anisocap/export/target_models.hpp"

namespace {

using anisocap::exports::vec3;

struct quadrature_point {
  vec3 l, v;
  double weight;  // dl dv cos_l
};

std::vector<quadrature_point> quadrature(double sx, double sy, int slopes, int zeniths, int azimuths) {
  std::vector<quadrature_point> out;
  const double max_slope = 6, pi = std::numbers::pi, max_zenith = 80 * pi / 180;
  const double tx_max = std::asinh(max_slope / sx), ty_max = std::asinh(max_slope / sy);
  for (int iz = 0; iz < zeniths; ++iz) {
    const double theta = (iz + 0.5) / zeniths * max_zenith;
    for (int ia = 0; ia < azimuths; ++ia) {
      const double phi = (ia + 0.5) / azimuths * pi / 2;
      const vec3 v{std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
      const double dv = std::sin(theta) * (max_zenith / zeniths) * (pi / 2 / azimuths);
      for (int i = 0; i < slopes; ++i)
        for (int j = 0; j < slopes; ++j) {
          const double tx = tx_max * (2 * (i + 0.5) / slopes - 1), ty = ty_max * (2 * (j + 0.5) / slopes - 1);
          const double px = sx * std::sinh(tx), py = sy * std::sinh(ty);
          const double dpx = sx * std::cosh(tx) * 2 * tx_max / slopes, dpy = sy * std::cosh(ty) * 2 * ty_max / slopes;
          const double norm = std::sqrt(1 + px * px + py * py);
          const vec3 h{-px / norm, -py / norm, 1 / norm};
          const double vh = v[0] * h[0] + v[1] * h[1] + v[2] * h[2];
          if (vh <= 0) continue;
          const vec3 l{2 * vh * h[0] - v[0], 2 * vh * h[1] - v[1], 2 * vh * h[2] - v[2]};
          if (l[2] <= 1e-4) continue;
          out.push_back({l, v, dv * 4 * vh * h[2] * h[2] * h[2] * dpx * dpy * l[2]});
        }
    }
  }
  return out;
}

// The Ward lobe alone: ward_evaluate with no diffuse, a'_s = 1 and F0 = 1 (Schlick's ratio is then 1).
double ward_lobe(const vec3& l, const vec3& v, double sx, double sy) {
  const anisocap::ward_parameters<double> p{{0, 0, 0}, {1, 1, 1}, sx, sy, 1.0, 0, 0, 0};
  return anisocap::ward_evaluate(p, l, v)[0];
}

struct lobe_case {
  std::vector<quadrature_point> points;
  std::vector<double> ward;
  double total = 0;
  double sx, sy;
  // E for GGX widths a = (kx sx, ky sy), clamped to 1 as every target clamps them, and gain g.
  double error(double kx, double ky, double g) const {
    double d = 0;
    const double ax = std::min(kx * sx, 1.0), ay = std::min(ky * sy, 1.0);
    for (std::size_t i = 0; i < points.size(); ++i)
      d += points[i].weight * std::abs(g * anisocap::exports::ggx_specular(points[i].l, points[i].v, ax, ay) - ward[i]);
    return d / total;
  }
};

// Minimises e over log(kx), log(ky) and, when `gain`, log(g), from k = 0.9, g = 1.
template <class E>
std::array<double, 4> compass_search(const E& e, bool gain) {
  std::array<double, 3> x{std::log(0.9), std::log(0.9), 0.0};
  auto f = [&](const std::array<double, 3>& p) { return e(std::exp(p[0]), std::exp(p[1]), std::exp(p[2])); };
  double best = f(x);
  for (double step = 0.25; step > 2e-3;) {
    bool improved = false;
    for (int k = 0; k < (gain ? 3 : 2); ++k)
      for (int sign : {-1, 1}) {
        std::array<double, 3> t = x;
        t[k] += sign * step;
        const double v = f(t);
        if (v < best) best = v, x = t, improved = true;
      }
    if (!improved) step /= 2;
  }
  return {best, std::exp(x[0]), std::exp(x[1]), std::exp(x[2])};
}

}  // namespace

int main(int argc, char** argv) {
  int slopes = 24, zeniths = 8, azimuths = 3;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string a = argv[i];
    const int v = std::atoi(argv[i + 1]);
    if (a == "--slopes") slopes = v;
    else if (a == "--zeniths") zeniths = v;
    else if (a == "--azimuths") azimuths = v;
    else { std::fprintf(stderr, "ggx_lobe_fit: unknown option %s\n", a.c_str()); return 2; }
  }
  if (argc % 2 == 0 || slopes < 2 || zeniths < 1 || azimuths < 1) {
    std::fprintf(stderr, "usage: anisocap_study_ggx_lobe_fit [--slopes N>=2] [--zeniths N>=1] [--azimuths N>=1]\n");
    return 2;
  }
  const double widths[] = {0.02, 0.05, 0.1, 0.2, 0.4}, aspects[] = {1, 2, 4, 8};
  std::vector<std::array<double, 2>> lobes;
  for (double sy : widths)
    for (double aspect : aspects)
      if (sy * aspect <= 0.8) lobes.push_back({sy * aspect, sy});
  std::vector<std::array<double, 11>> rows(lobes.size());
#pragma omp parallel for schedule(dynamic)
  for (std::size_t i = 0; i < lobes.size(); ++i) {
    lobe_case c;
    c.sx = lobes[i][0], c.sy = lobes[i][1];
    c.points = quadrature(c.sx, c.sy, slopes, zeniths, azimuths);
    for (const quadrature_point& p : c.points) {
      c.ward.push_back(ward_lobe(p.l, p.v, c.sx, c.sy));
      c.total += p.weight * c.ward.back();
    }
    auto e = [&](double kx, double ky, double g) { return c.error(kx, ky, g); };
    const auto widths_only = compass_search(e, false), with_gain = compass_search(e, true);
    rows[i] = {c.sx, c.sy, c.error(0.9, 0.9, 1), c.error(1, 1, 1), widths_only[0], widths_only[1], widths_only[2],
               with_gain[0], with_gain[1], with_gain[2], with_gain[3]};
  }
  std::printf("| sigma_x | sigma_y | k = 0.9 | k = 1 | best widths (k_x, k_y) | best widths and gain (k_x, k_y, g) |\n");
  std::printf("|---|---|---|---|---|---|\n");
  double mean[4] = {};
  for (const auto& r : rows) {
    std::printf("| %.2f | %.2f | %.1f%% | %.1f%% | %.1f%% (%.2f, %.2f) | %.1f%% (%.2f, %.2f, %.2f) |\n", r[0], r[1], 100 * r[2], 100 * r[3],
                100 * r[4], r[5], r[6], 100 * r[7], r[8], r[9], r[10]);
    mean[0] += r[2], mean[1] += r[3], mean[2] += r[4], mean[3] += r[7];
  }
  const double n = double(rows.size());
  std::printf("| **mean** | | **%.1f%%** | **%.1f%%** | **%.1f%%** | **%.1f%%** |\n", 100 * mean[0] / n, 100 * mean[1] / n, 100 * mean[2] / n,
              100 * mean[3] / n);
}
