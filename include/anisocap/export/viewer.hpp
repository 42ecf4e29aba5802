#pragma once
/// @file
/// The interactive viewer: one self-contained HTML page (WebGL2, no network access) that renders a
/// map set with the project's BRDF (brdf/ward.hpp, docs/method.md sections 3-4) under a point
/// light, in the renderer's scene model (render/renderer.hpp): the material lies in z = 0, its
/// longest side is 1, the point light has inverse-square falloff, and each point is seen from the
/// camera position. The maps are embedded as base64 float32 data and read with texelFetch, so the
/// shader sees the parameters exactly as the renderer does.
///
/// In the page: drag to orbit the camera, shift-drag (or right-drag) to move the light over the
/// material, the wheel to move the camera closer, sliders for exposure and light height, a menu
/// for what to show (the render or one map, shown as the map previews of data/map_io.hpp). The
/// page's URL fragment sets and records the view, e.g.
/// `material.html#camera=0.3,-0.2,1.5&light=0,0.5,1&exposure=-1&mode=render&view=texel&ui=0`:
///   camera, light  positions in scene units;  intensity  light intensity r,g,b (default: pi |light|^2,
///   so a white Lambertian texel under the light renders as 1);  exposure  stops;  mode  render,
///   diffuse, specular, lobes, fresnel, normal, rotation;  view  perspective (default) or texel
///   (one canvas pixel per texel, row 0 at the top: the image `anisocap render` writes);  repeat
///   1 (default) or 2: in the perspective view, the material laid 2 x 2 times side by side, as a
///   tile (`anisocap export --tileable`, export/tileable.hpp) covers a surface, centred on the
///   origin (the texel view always shows one copy);  overlay  none (default), diffuse, specular, lobes,
///   fresnel, normal or rotation: with the uncertainty (viewer_options::uncertainty), that map's
///   parameters' largest ratio (viewer_options::uncertainty) blended in magenta over the view;  ui  0 hides the controls.
/// Displayed values are 2^exposure R, clamped to [0, 1] and sRGB-encoded (the inverse is exact up
/// to 8-bit rounding), so a screenshot can be compared with a render.
#include <cstdint>
#include <filesystem>
#include <string>
#include <stdexcept>
#include <string_view>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/data/image_io.hpp"

namespace anisocap {

/// Options of the viewer page.
struct viewer_options {
  std::string title = "anisocap material";  ///< page title (HTML-escaped when written)
  /// How uncertain each parameter of each texel is, as its posterior standard deviation over its
  /// standard deviation before any photograph (pipeline/uncertainty.hpp, uncertainty_result::ratio():
  /// 0 where the photographs fix it, 1 where they say nothing), or null: with it the page offers
  /// the uncertainty overlay.
  const material_maps* uncertainty = nullptr;
};

namespace detail {

/// Standard base64 (RFC 4648) of `size` bytes.
inline std::string base64(const unsigned char* data, std::size_t size) {
  static constexpr char table[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < size; i += 3) {
    const std::uint32_t v = std::uint32_t(data[i]) << 16 | std::uint32_t(data[i + 1]) << 8 | data[i + 2];
    out += table[v >> 18], out += table[(v >> 12) & 63], out += table[(v >> 6) & 63], out += table[v & 63];
  }
  if (i + 1 == size) {
    const std::uint32_t v = std::uint32_t(data[i]) << 16;
    out += table[v >> 18], out += table[(v >> 12) & 63], out += "==";
  } else if (i + 2 == size) {
    const std::uint32_t v = std::uint32_t(data[i]) << 16 | std::uint32_t(data[i + 1]) << 8;
    out += table[v >> 18], out += table[(v >> 12) & 63], out += table[(v >> 6) & 63], out += '=';
  }
  return out;
}

/// Escapes &, <, >, " for HTML text and attributes.
inline std::string html_escape(std::string_view s) {
  std::string out;
  for (char c : s) {
    if (c == '&') out += "&amp;";
    else if (c == '<') out += "&lt;";
    else if (c == '>') out += "&gt;";
    else if (c == '"') out += "&quot;";
    else out += c;
  }
  return out;
}

/// The maps as three RGBA float32 textures, texel after texel, row 0 (the top row) first:
/// (a_d rgb, F0), (a'_s rgb, alpha), (sigma_x, sigma_y, n_x, n_y).
inline std::vector<float> viewer_texels(const material_maps& m) {
  static constexpr int layout[3][4] = {{diffuse_r, diffuse_g, diffuse_b, fresnel_f0},
                                       {specular_r, specular_g, specular_b, rotation},
                                       {lobe_x, lobe_y, normal_x, normal_y}};
  const std::size_t n = m.texel_count();
  std::vector<float> out(3 * 4 * n);
  for (int t = 0; t < 3; ++t)
    for (std::size_t i = 0; i < n; ++i)
      for (int c = 0; c < 4; ++c) out[(t * n + i) * 4 + c] = m.plane(layout[t][c])[i];
  return out;
}

/// The page, with @WIDTH@, @HEIGHT@, @TITLE@, @DATA@ and @UNCERTAINTY@ to fill in.
inline constexpr std::string_view viewer_template = R"HTML(<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>@TITLE@</title>
<style>
html, body { margin: 0; height: 100%; overflow: hidden; background: #202020; font: 13px sans-serif; color: #ddd; }
canvas { display: block; }
#ui { position: absolute; top: 8px; left: 8px; background: rgba(0,0,0,0.6); padding: 8px; border-radius: 4px; }
#ui label { display: block; margin: 4px 0; }
</style></head><body>
<canvas id="view"></canvas>
<div id="ui">
<b>@TITLE@</b> (@WIDTH@ x @HEIGHT@ texels)<br>
drag: orbit camera &middot; shift-drag: move light &middot; wheel: zoom
<label>exposure <input id="exposure" type="range" min="-8" max="8" step="0.1" value="0"> <span id="exposure_value"></span> stops</label>
<label>light height <input id="height" type="range" min="0.05" max="3" step="0.01" value="1"></label>
<label>show <select id="mode">
<option value="render">render</option><option value="diffuse">diffuse albedo</option>
<option value="specular">specular albedo</option><option value="lobes">lobe widths</option>
<option value="fresnel">Fresnel F0</option><option value="normal">normal</option>
<option value="rotation">rotation</option></select></label>
<label><input id="repeat" type="checkbox"> 2 x 2 repeats</label>
<label id="overlay_label">uncertainty of <select id="overlay">
<option value="none">(none)</option><option value="diffuse">diffuse albedo</option>
<option value="specular">specular albedo</option><option value="lobes">lobe widths</option>
<option value="fresnel">Fresnel F0</option><option value="normal">normal</option>
<option value="rotation">rotation</option></select></label>
<div id="overlay_key">magenta: sd / prior sd, from 0 (fixed by the photographs) to 1 (they say nothing)</div>
</div>
<script id="maps" type="application/octet-stream">@DATA@</script>
<script id="uncertainty" type="application/octet-stream">@UNCERTAINTY@</script>
<script>
"use strict";
const W = @WIDTH@, H = @HEIGHT@, N = Math.max(W, H);
const modes = ["render", "diffuse", "specular", "lobes", "fresnel", "normal", "rotation"];
const overlays = ["none", "diffuse", "specular", "lobes", "fresnel", "normal", "rotation"];
const state = { camera: [0, -0.9, 1.6], light: [0.3, 0.3, 1.0], intensity: null, exposure: 0, mode: "render", view: "perspective", repeat: 1, overlay: "none", ui: true };
function parseHash() {
  for (const part of location.hash.replace(/^#/, "").split("&")) {
    const [key, value] = part.split("=");
    if (value === undefined) continue;
    const numbers = value.split(",").map(Number);
    if ((key === "camera" || key === "light" || key === "intensity") && numbers.length === 3 && numbers.every(Number.isFinite)) state[key] = numbers;
    else if (key === "exposure" && Number.isFinite(numbers[0])) state.exposure = numbers[0];
    else if (key === "mode" && modes.includes(value)) state.mode = value;
    else if (key === "view" && (value === "texel" || value === "perspective")) state.view = value;
    else if (key === "repeat" && (value === "1" || value === "2")) state.repeat = +value;
    else if (key === "overlay" && overlays.includes(value)) state.overlay = value;
    else if (key === "ui") state.ui = value !== "0";
  }
}
parseHash();
const canvas = document.getElementById("view");
const gl = canvas.getContext("webgl2", { preserveDrawingBuffer: true, antialias: false });
if (!gl) document.body.innerHTML = "<p style='padding:2em'>This page needs WebGL2.</p>";
const bytes = Uint8Array.from(atob(document.getElementById("maps").textContent.trim()), c => c.charCodeAt(0));
const texels = new Float32Array(bytes.buffer);
function makeTexture(unit, offset) {
  const t = gl.createTexture();
  gl.activeTexture(gl.TEXTURE0 + unit);
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, W, H, 0, gl.RGBA, gl.FLOAT, texels.subarray(offset, offset + 4 * W * H));
}
for (let t = 0; t < 3; ++t) makeTexture(t, t * 4 * W * H);
// The uncertainty (sd / prior sd, laid out as the maps), when the page has it; else zeros.
const uncertaintyText = document.getElementById("uncertainty").textContent.trim();
const hasUncertainty = uncertaintyText.length > 0;
const ratios = hasUncertainty ? new Float32Array(Uint8Array.from(atob(uncertaintyText), c => c.charCodeAt(0)).buffer)
                              : new Float32Array(3 * 4 * W * H);
for (let t = 0; t < 3; ++t) {
  const tex = gl.createTexture();
  gl.activeTexture(gl.TEXTURE3 + t);
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, W, H, 0, gl.RGBA, gl.FLOAT, ratios.subarray(t * 4 * W * H, (t + 1) * 4 * W * H));
}
const vertexSource = `#version 300 es
uniform mat4 view_projection;
uniform vec2 half_extent;
uniform bool texel_view;
uniform highp int repeat;  // highp in both stages: a uniform shared by them must match
out vec2 uv;
void main() {
  vec2 corner = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1));
  uv = corner;
  vec3 p = vec3((corner * 2.0 - 1.0) * half_extent * float(repeat), 0.0);
  gl_Position = texel_view ? vec4(corner * 2.0 - 1.0, 0.0, 1.0) : view_projection * vec4(p, 1.0);
}`;
// The BRDF of brdf/ward.hpp (ward_evaluate) with the scene model of render/renderer.hpp.
const fragmentSource = `#version 300 es
precision highp float;
precision highp sampler2D;
uniform sampler2D maps0, maps1, maps2, spread0, spread1, spread2;
uniform int overlay;
uniform vec3 camera, light, intensity;
uniform float exposure_scale;
uniform int mode;
uniform bool texel_view;
uniform ivec2 size;
uniform highp int repeat;  // highp in both stages: a uniform shared by them must match
in vec2 uv;
out vec4 colour;
const float PI = 3.14159265358979;
vec3 radiance(vec4 m0, vec4 m1, vec4 m2, vec3 p) {
  vec3 diffuse = m0.rgb, specular = m1.rgb;
  float f0 = max(m0.a, 1e-4), alpha = m1.a, sx = max(m2.x, 1e-4), sy = max(m2.y, 1e-4);
  float nx = max(m2.z, -1.0), ny = max(m2.w, -1.0);
  vec3 n = vec3(nx, ny, sqrt(max(1.0 - nx * nx - ny * ny, 1e-6)));
  vec3 t = normalize(vec3(1.0, 0.0, 0.0) - nx * n);  // tangent: t_g = (1, 0, 0) made normal to n
  vec3 b = cross(n, t);
  vec3 x = cos(alpha) * t + sin(alpha) * b, y = -sin(alpha) * t + cos(alpha) * b;
  vec3 to_light = light - p;
  float r2 = max(dot(to_light, to_light), 1e-6);
  vec3 l = to_light / sqrt(r2);
  vec3 to_camera = camera - p;
  vec3 v = to_camera / sqrt(max(dot(to_camera, to_camera), 1e-6));
  float nl = dot(n, l), nv = dot(n, v);
  if (nl <= 0.0 || nv <= 0.0) return vec3(0.0);
  vec3 h = l + v;
  float hh = max(dot(h, h), 1e-12);
  float hx = dot(x, h), hy = dot(y, h), hz = max(dot(n, h), 1e-6);
  float m = max(1.0 - dot(v, h) / sqrt(hh), 0.0);
  float fresnel_ratio = 1.0 + (1.0 / f0 - 1.0) * m * m * m * m * m;  // Schlick F / F0
  float e = -(hx * hx / (sx * sx) + hy * hy / (sy * sy)) / (hz * hz) + log(hh * fresnel_ratio / (PI * sx * sy)) - 4.0 * log(hz);
  float lobe = exp(min(e, 50.0));
  return (diffuse / PI + specular * lobe) * nl * intensity / r2;
}
vec3 srgb(vec3 c) {
  c = clamp(c, 0.0, 1.0);
  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
void main() {
  ivec2 texel;
  if (texel_view) texel = ivec2(gl_FragCoord.x, float(size.y) - gl_FragCoord.y);
  else {  // uv spans the repeat x repeat copies: the texel of the copy under this point
    vec2 local = fract(uv * float(repeat));
    texel = ivec2(local.x * float(size.x), (1.0 - local.y) * float(size.y));
  }
  texel = clamp(texel, ivec2(0), size - 1);
  vec4 m0 = texelFetch(maps0, texel, 0), m1 = texelFetch(maps1, texel, 0), m2 = texelFetch(maps2, texel, 0);
  float n = float(max(size.x, size.y));
  vec3 p;  // texel centre in the texel view (as the renderer), the exact point in perspective
  if (texel_view) p = vec3((float(texel.x) + 0.5 - 0.5 * float(size.x)) / n, (0.5 * float(size.y) - (float(texel.y) + 0.5)) / n, 0.0);
  else p = vec3((uv.x - 0.5) * float(size.x * repeat) / n, (uv.y - 0.5) * float(size.y * repeat) / n, 0.0);
  vec3 c;
  if (mode == 0) c = srgb(exposure_scale * radiance(m0, m1, m2, p));
  else if (mode == 1) c = srgb(m0.rgb);
  else if (mode == 2) c = srgb(m1.rgb);
  else if (mode == 3) c = vec3(m2.x, m2.y, 0.0);
  else if (mode == 4) c = srgb(vec3(m0.a));
  else if (mode == 5) c = 0.5 + 0.5 * vec3(m2.z, m2.w, sqrt(max(1.0 - m2.z * m2.z - m2.w * m2.w, 0.0)));
  else c = vec3(m1.a / PI + 0.5);
  if (overlay > 0) {  // the largest sd / prior sd of the parameters the chosen map holds
    vec4 s0 = texelFetch(spread0, texel, 0), s1 = texelFetch(spread1, texel, 0), s2 = texelFetch(spread2, texel, 0);
    float r = overlay == 1 ? max(s0.r, max(s0.g, s0.b)) : overlay == 2 ? max(s1.r, max(s1.g, s1.b))
            : overlay == 3 ? max(s2.x, s2.y) : overlay == 4 ? s0.a : overlay == 5 ? max(s2.z, s2.w) : s1.a;
    c = mix(c, vec3(1.0, 0.0, 1.0), 0.8 * clamp(r, 0.0, 1.0));
  }
  colour = vec4(c, 1.0);
}`;
function compile(type, source) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}
const program = gl.createProgram();
gl.attachShader(program, compile(gl.VERTEX_SHADER, vertexSource));
gl.attachShader(program, compile(gl.FRAGMENT_SHADER, fragmentSource));
gl.linkProgram(program);
if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
gl.useProgram(program);
const u = name => gl.getUniformLocation(program, name);
gl.uniform1i(u("maps0"), 0); gl.uniform1i(u("maps1"), 1); gl.uniform1i(u("maps2"), 2);
gl.uniform1i(u("spread0"), 3); gl.uniform1i(u("spread1"), 4); gl.uniform1i(u("spread2"), 5);
gl.uniform2i(u("size"), W, H);
gl.uniform2f(u("half_extent"), 0.5 * W / N, 0.5 * H / N);
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalise = a => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
// Column-major perspective(fov 35 degrees) * look-at(camera -> origin).
function viewProjection(aspect) {
  const f = normalise(sub([0, 0, 0], state.camera));
  let up = Math.abs(f[1]) > 0.999 ? [0, 0, 1] : [0, 1, 0];
  if (Math.abs(dot(f, up)) > 0.999) up = [1, 0, 0];
  const s = normalise(cross(f, up)), v = cross(s, f), e = state.camera;
  const view = [s[0], v[0], -f[0], 0, s[1], v[1], -f[1], 0, s[2], v[2], -f[2], 0, -dot(s, e), -dot(v, e), dot(f, e), 1];
  const t = 1 / Math.tan(35 * Math.PI / 360), near = 0.01, far = 100;
  const proj = [t / aspect, 0, 0, 0, 0, t, 0, 0, 0, 0, (far + near) / (near - far), -1, 0, 0, 2 * far * near / (near - far), 0];
  const out = new Array(16).fill(0);
  for (let c = 0; c < 4; ++c) for (let r = 0; r < 4; ++r) for (let k = 0; k < 4; ++k) out[c * 4 + r] += proj[k * 4 + r] * view[c * 4 + k];
  return out;
}
function intensity() {
  if (state.intensity) return state.intensity;
  const i = Math.PI * dot(state.light, state.light);
  return [i, i, i];
}
function draw() {
  const texel = state.view === "texel";
  const w = texel ? W : window.innerWidth, h = texel ? H : window.innerHeight;
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; canvas.style.width = w + "px"; canvas.style.height = h + "px"; }
  gl.viewport(0, 0, w, h);
  gl.clearColor(0.12, 0.12, 0.12, 1);
  gl.clear(gl.COLOR_BUFFER_BIT);
  gl.uniform1i(u("texel_view"), texel ? 1 : 0);
  gl.uniformMatrix4fv(u("view_projection"), false, viewProjection(w / h));
  gl.uniform3fv(u("camera"), state.camera);
  gl.uniform3fv(u("light"), state.light);
  gl.uniform3fv(u("intensity"), intensity());
  gl.uniform1f(u("exposure_scale"), Math.pow(2, state.exposure));
  gl.uniform1i(u("mode"), modes.indexOf(state.mode));
  gl.uniform1i(u("repeat"), texel ? 1 : state.repeat);
  gl.uniform1i(u("overlay"), hasUncertainty ? overlays.indexOf(state.overlay) : 0);
  gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
  document.getElementById("exposure_value").textContent = state.exposure.toFixed(1);
}
let pending = false;
function redraw(record) {
  if (record) {
    const f = a => a.map(x => +x.toFixed(4)).join(",");
    history.replaceState(null, "", "#camera=" + f(state.camera) + "&light=" + f(state.light) + "&exposure=" + state.exposure +
                         "&mode=" + state.mode + "&view=" + state.view + (state.repeat !== 1 ? "&repeat=" + state.repeat : "") + (state.overlay !== "none" ? "&overlay=" + state.overlay : "") + (state.intensity ? "&intensity=" + f(state.intensity) : ""));
  }
  if (!pending) { pending = true; requestAnimationFrame(() => { pending = false; draw(); }); }
}
const ui = document.getElementById("ui");
if (!state.ui) ui.style.display = "none";
const exposure = document.getElementById("exposure"), height = document.getElementById("height"), mode = document.getElementById("mode");
const repeat = document.getElementById("repeat");
exposure.value = state.exposure; height.value = state.light[2]; mode.value = state.mode; repeat.checked = state.repeat === 2;
repeat.onchange = () => { state.repeat = repeat.checked ? 2 : 1; redraw(true); };
const overlay = document.getElementById("overlay");
overlay.value = state.overlay;
overlay.onchange = () => { state.overlay = overlay.value; redraw(true); };
if (!hasUncertainty) { document.getElementById("overlay_label").style.display = "none"; document.getElementById("overlay_key").style.display = "none"; }
exposure.oninput = () => { state.exposure = +exposure.value; redraw(true); };
height.oninput = () => { state.light[2] = +height.value; redraw(true); };
mode.onchange = () => { state.mode = mode.value; redraw(true); };
let drag = null;
canvas.addEventListener("contextmenu", e => e.preventDefault());
canvas.addEventListener("pointerdown", e => { drag = { x: e.clientX, y: e.clientY, light: e.shiftKey || e.button === 2 }; canvas.setPointerCapture(e.pointerId); });
canvas.addEventListener("pointerup", () => { drag = null; });
canvas.addEventListener("pointermove", e => {
  if (!drag) return;
  const dx = (e.clientX - drag.x) / canvas.clientHeight, dy = (e.clientY - drag.y) / canvas.clientHeight;
  drag.x = e.clientX; drag.y = e.clientY;
  if (drag.light) {
    state.light[0] += 2 * dx; state.light[1] -= 2 * dy;
  } else {  // orbit about the material's centre, keeping the camera's distance
    const c = state.camera, r = Math.hypot(c[0], c[1], c[2]);
    let azimuth = Math.atan2(c[1], c[0]) - 3 * dx;
    let elevation = Math.min(Math.max(Math.asin(c[2] / r) + 3 * dy, 0.05), Math.PI / 2 - 1e-3);
    state.camera = [r * Math.cos(elevation) * Math.cos(azimuth), r * Math.cos(elevation) * Math.sin(azimuth), r * Math.sin(elevation)];
  }
  redraw(true);
});
canvas.addEventListener("wheel", e => {
  e.preventDefault();
  const k = Math.exp(0.001 * e.deltaY);
  state.camera = state.camera.map(x => x * k);
  redraw(true);
}, { passive: false });
window.addEventListener("resize", () => redraw(false));
window.addEventListener("hashchange", () => { parseHash(); redraw(false); });
draw();
document.title = "@TITLE@ (ready)";
</script></body></html>
)HTML";

/// Replaces every `key` in `text` with `value`.
inline void replace_all(std::string& text, std::string_view key, std::string_view value) {
  for (std::size_t at = text.find(key); at != std::string::npos; at = text.find(key, at + value.size())) text.replace(at, key.size(), value);
}

}  // namespace detail

/// The viewer page for `maps` (see the file comment).
inline std::string viewer_html(const material_maps& maps, const viewer_options& options = {}) {
  const std::vector<float> texels = detail::viewer_texels(maps);
  std::string spread;  // sd / prior sd in the maps' layout, when given
  if (options.uncertainty) {
    if (options.uncertainty->width() != maps.width() || options.uncertainty->height() != maps.height())
      throw std::invalid_argument("viewer_html: the uncertainty maps' size differs from the maps'");
    const std::vector<float> r = detail::viewer_texels(*options.uncertainty);
    spread = detail::base64(reinterpret_cast<const unsigned char*>(r.data()), r.size() * sizeof(float));
  }
  // float32 little-endian, as JavaScript's Float32Array reads it on every platform browsers run on.
  const std::string data = detail::base64(reinterpret_cast<const unsigned char*>(texels.data()), texels.size() * sizeof(float));
  std::string page(detail::viewer_template);
  detail::replace_all(page, "@WIDTH@", std::to_string(maps.width()));
  detail::replace_all(page, "@HEIGHT@", std::to_string(maps.height()));
  detail::replace_all(page, "@TITLE@", detail::html_escape(options.title));
  page.replace(page.find("@UNCERTAINTY@"), 13, spread);  // base64 holds no '@': the next search never matches inside it
  const std::size_t at = page.find("@DATA@");
  page.replace(at, 6, data);
  return page;
}

/// Writes the viewer page for `maps` to `path` atomically (temporary name, then rename).
inline void write_viewer(const material_maps& maps, const std::filesystem::path& path, const viewer_options& options = {}) {
  if (maps.texel_count() == 0) throw io_error(path, "cannot write a viewer for an empty map set");
  write_file_atomically(path, viewer_html(maps, options));
}

}  // namespace anisocap
