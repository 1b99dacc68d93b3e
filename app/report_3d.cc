// The 3-D view of the run report (report_sections.h): the part's surface as a mesh coloured by deviation
// (each loop's interpolated deviation and systematic field), the probe points with their values on
// hover, the tool path as an optional overlay, orbit/zoom/pan — drawn by three.js from Debian's
// libjs-three, inlined so the report stays one file that needs no network — and a static SVG projection
// of the same mesh for print and for browsers without WebGL.
//
// The mesh: the grid of InterpolateField (report_svg.h) over the probe points' (x, y) box, its height
// the probe points' z interpolated the same way (a picture of the part, not a measurement of it), blank
// where the maps are blank. Colours: a table of DivergingColour over ±max_abs, the maps' scale.

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string_view>

#include <fmt/format.h>

#include "app/report_sections.h"
#include "app/report_svg.h"
#include "core/log.h"
#include "core/number_text.h"

#ifndef FORMLOOP_THREE_JS_DIR
#define FORMLOOP_THREE_JS_DIR "/usr/share/javascript/three"
#endif

namespace formloop::app::report {
namespace {

namespace fs = std::filesystem;

constexpr int kMeshCells = 64;
constexpr std::size_t kMaxPoints = 5000;
constexpr std::size_t kMaxPathPoints = 8000;

// three.min.js and its OrbitControls from the libjs-three package: the folder found at build time, or
// $FORMLOOP_THREE_JS_DIR where a system keeps three.js elsewhere.
Result<std::string> ReadPackageScript(const std::string& relative) {
  const char* override_dir = std::getenv("FORMLOOP_THREE_JS_DIR");
  const fs::path dir = override_dir && *override_dir ? fs::path(override_dir) : fs::path(FORMLOOP_THREE_JS_DIR);
  const fs::path path = dir / relative;
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Status::NotFound("the report's 3-D view needs " + path.string() +
                            " from the Debian package libjs-three; install it (scripts/setup.sh deps, or apt-get "
                            "install libjs-three)");
  }
  std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  if (text.find("</script") != std::string::npos) {
    return Status::Internal(path.string() + " contains \"</script\" and cannot be inlined");
  }
  return text;
}

// Numbers for the embedded JSON: fixed decimals, "null" for NaN.
void AppendNumbers(std::string& out, const std::vector<double>& values, int decimals) {
  out += '[';
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (i) out += ',';
    out += std::isfinite(values[i]) ? FormatFixed(values[i], decimals) : "null";
  }
  out += ']';
}

// Every k-th index so that at most `limit` remain.
std::size_t Stride(std::size_t n, std::size_t limit) { return std::max<std::size_t>(1, (n + limit - 1) / limit); }

// Cut moves of toolpath/toolpath.csv (cc_x, cc_y, cc_z, pass), thinned to at most kMaxPathPoints: flat
// x, y, z triples and the pass of each point. Empty when the file is absent or has other columns.
void ReadToolPath(const fs::path& path, std::vector<double>* xyz, std::vector<double>* pass) {
  // Two passes over the file, one row at a time (a million-point path is ~170 MB of text): the cut moves are
  // counted, then every stride-th is kept.
  std::vector<std::string_view> cells;
  const auto split = [&cells](std::string_view line) {
    cells.clear();
    std::size_t begin = 0;
    while (begin < line.size()) {  // as std::getline(.., ','): no empty field after a final comma
      const std::size_t comma = std::min(line.find(',', begin), line.size());
      cells.push_back(line.substr(begin, comma - begin));
      begin = comma + 1;
    }
  };
  std::vector<std::string> header;
  std::size_t cx = 0, cy = 0, cz = 0, cp = 0, ck = 0;
  // Calls row() on every data row with as many cells as the header; false when the file or a column is missing.
  const auto for_each_row = [&](const auto& row) {
    std::ifstream in(path);
    if (!in) return false;
    header.clear();
    std::string line;
    while (std::getline(in, line)) {
      if (line.empty() || line[0] == '#') continue;
      split(line);
      if (header.empty()) {
        header.assign(cells.begin(), cells.end());
        auto column = [&](const char* name) {
          return static_cast<std::size_t>(std::find(header.begin(), header.end(), name) - header.begin());
        };
        cx = column("cc_x"), cy = column("cc_y"), cz = column("cc_z"), cp = column("pass"), ck = column("kind");
        if (std::max({cx, cy, cz, cp, ck}) >= header.size()) return false;
      } else if (cells.size() == header.size()) {
        row();
      }
    }
    return !header.empty();
  };
  std::size_t cuts = 0;
  if (!for_each_row([&] { cuts += cells[ck] == "cut"; })) return;
  const std::size_t stride = Stride(cuts, kMaxPathPoints);
  std::size_t k = 0;
  for_each_row([&] {
    if (cells[ck] != "cut" || k++ % stride != 0) return;
    double x, y, z, p;
    if (!ParseDouble(cells[cx], &x) || !ParseDouble(cells[cy], &y) || !ParseDouble(cells[cz], &z) ||
        !ParseDouble(cells[cp], &p)) {
      return;
    }
    xyz->insert(xyz->end(), {x, y, z});
    pass->push_back(p);
  });
}

struct Mesh {
  FieldGrid z;                              // heights (mm)
  std::vector<std::string> names;           // one per field
  std::vector<std::vector<double>> fields;  // on z's grid (µm)
};

Mesh BuildMesh(const RunData& run) {
  Mesh mesh;
  const LoopData& first = run.loops.front();
  const std::vector<double> x0 = Column(*first.points, "x"), y0 = Column(*first.points, "y");
  mesh.z = InterpolateField(x0, y0, Column(*first.points, "z"), kMeshCells, run.part_mask);
  for (const LoopData& loop : run.loops) {
    if (!loop.points) continue;
    const std::vector<double> x = Column(*loop.points, "x"), y = Column(*loop.points, "y");
    const std::string name = "loop " + std::to_string(loop.loop);
    const std::vector<double> ds = Column(*loop.points, "systematic_um");
    if (!ds.empty()) {
      mesh.names.push_back(name + ": systematic field d_s");
      mesh.fields.push_back(InterpolateField(x, y, ds, kMeshCells, run.part_mask).values);
    }
    mesh.names.push_back(name + ": measured deviation (interpolated)");
    mesh.fields.push_back(
        InterpolateField(x, y, Column(*loop.points, "deviation_um"), kMeshCells, run.part_mask).values);
  }
  // A loop's points may cover another box than loop 0's: such a field does not fit the mesh's grid.
  for (std::size_t f = mesh.fields.size(); f-- > 0;) {
    if (mesh.fields[f].size() != mesh.z.values.size()) {
      mesh.fields.erase(mesh.fields.begin() + static_cast<std::ptrdiff_t>(f));
      mesh.names.erase(mesh.names.begin() + static_cast<std::ptrdiff_t>(f));
    }
  }
  return mesh;
}

std::string DataJson(const RunData& run, const Mesh& mesh, double max_abs) {
  const FieldGrid& g = mesh.z;
  std::string out = fmt::format(
      "{{\"nx\":{},\"ny\":{},\"x0\":{},\"y0\":{},\"dx\":{},\"dy\":{},\"scale\":{},\"z\":", g.nx, g.ny,
      FormatFixed(g.x0, 4), FormatFixed(g.y0, 4), FormatFixed(g.dx, 5), FormatFixed(g.dy, 5), FormatFixed(max_abs, 3));
  AppendNumbers(out, g.values, 4);
  out += ",\"fields\":[";
  for (std::size_t f = 0; f < mesh.fields.size(); ++f) {
    out += fmt::format("{}{{\"name\":\"{}\",\"values\":", f ? "," : "", mesh.names[f]);
    AppendNumbers(out, mesh.fields[f], 2);
    out += '}';
  }
  out += "],\"points\":[";
  bool first_loop = true;
  for (const LoopData& loop : run.loops) {
    if (!loop.points) continue;
    const std::vector<double> x = Column(*loop.points, "x"), y = Column(*loop.points, "y"),
                              z = Column(*loop.points, "z"), d = Column(*loop.points, "deviation_um");
    std::vector<double> xyz, dev;
    for (std::size_t i = 0; i < x.size(); i += Stride(x.size(), kMaxPoints)) {
      xyz.insert(xyz.end(), {x[i], y[i], z[i]});
      dev.push_back(d[i]);
    }
    out += fmt::format("{}{{\"loop\":{},\"xyz\":", first_loop ? "" : ",", loop.loop);
    AppendNumbers(out, xyz, 3);
    out += ",\"dev\":";
    AppendNumbers(out, dev, 2);
    out += '}';
    first_loop = false;
  }
  std::vector<double> path, pass;
  ReadToolPath(run.dir / "toolpath" / "toolpath.csv", &path, &pass);
  out += "],\"path\":";
  AppendNumbers(out, path, 3);
  out += ",\"pass\":";
  AppendNumbers(out, pass, 0);
  out += ",\"lut\":[";
  for (int k = 0; k <= 64; ++k) {
    out += fmt::format("{}\"{}\"", k ? "," : "", HexOf(DivergingColour(-1 + k / 32.0, 1)));
  }
  return out + "]}";
}

// The static picture: the mesh (first field) seen obliquely, quads painted back to front, for print.
std::string ProjectionSvg(const Mesh& mesh, double max_abs) {
  const FieldGrid& g = mesh.z;
  const std::vector<double>& v = mesh.fields.front();
  const double az = -0.6, el = 0.55;  // rad: view from the front left, above
  const double ca = std::cos(az), sa = std::sin(az), ce = std::cos(el), se = std::sin(el);
  // Coarser than the mesh: every second node.
  const int step = g.nx > 40 ? 2 : 1;
  struct Quad {
    double depth;
    double sx[4], sy[4];
    double value;
  };
  std::vector<Quad> quads;
  double zmid = 0;
  int nz = 0;
  for (double z : g.values) {
    if (std::isfinite(z)) zmid += z, ++nz;
  }
  zmid = nz ? zmid / nz : 0;
  const double cxm = g.x0 + g.nx * g.dx / 2, cym = g.y0 + g.ny * g.dy / 2;
  auto node = [&](int i, int j, double* sx, double* sy, double* depth) {
    const double x = g.x0 + (i + 0.5) * g.dx - cxm, y = g.y0 + (j + 0.5) * g.dy - cym, z = g.At(i, j) - zmid;
    const double across = ca * x - sa * y, away = sa * x + ca * y;
    *sx = across;
    *sy = -(z * ce + away * se);
    *depth = away * ce - z * se;
  };
  double lo_x = 1e300, hi_x = -1e300, lo_y = 1e300, hi_y = -1e300;
  for (int j = 0; j + step < g.ny; j += step) {
    for (int i = 0; i + step < g.nx; i += step) {
      const int ci[4] = {i, i + step, i + step, i}, cj[4] = {j, j, j + step, j + step};
      Quad q{0, {}, {}, 0};
      bool ok = true;
      double value = 0;
      for (int k = 0; k < 4 && ok; ++k) {
        const double z = g.At(ci[k], cj[k]);
        const double f = v[static_cast<std::size_t>(cj[k]) * g.nx + ci[k]];
        ok = std::isfinite(z) && std::isfinite(f);
        double d = 0;
        if (ok) node(ci[k], cj[k], &q.sx[k], &q.sy[k], &d);
        q.depth += d / 4;
        value += f / 4;
      }
      if (!ok) continue;
      q.value = value;
      for (int k = 0; k < 4; ++k) {
        lo_x = std::min(lo_x, q.sx[k]), hi_x = std::max(hi_x, q.sx[k]);
        lo_y = std::min(lo_y, q.sy[k]), hi_y = std::max(hi_y, q.sy[k]);
      }
      quads.push_back(q);
    }
  }
  if (quads.empty()) return "";
  std::stable_sort(quads.begin(), quads.end(), [](const Quad& a, const Quad& b) { return a.depth > b.depth; });
  const double width = 640, height = 420, margin = 20;
  const double s = std::min((width - 2 * margin) / (hi_x - lo_x), (height - 70 - 2 * margin) / (hi_y - lo_y));
  std::string out = fmt::format(
      "<svg class=\"chart\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {0} {1}\" width=\"{0}\" "
      "height=\"{1}\" role=\"img\"><title>{2}</title>\n",
      width, height, Esc("The part in 3-D (static view): " + mesh.names.front()));
  out += "<g stroke-width=\"0.3\">";
  for (const Quad& q : quads) {
    const std::string colour = HexOf(DivergingColour(q.value, max_abs));
    out += "<path fill=\"" + colour + "\" stroke=\"" + colour + "\" d=\"";
    for (int k = 0; k < 4; ++k) {
      out += fmt::format("{}{} {}", k ? "L" : "M", FormatFixed(margin + (q.sx[k] - lo_x) * s, 1),
                         FormatFixed(margin + (q.sy[k] - lo_y) * s, 1));
    }
    out += "Z\"/>";
  }
  out += "</g>\n";
  const double bar_top = height - 56;
  out += fmt::format("<rect x=\"140\" y=\"{}\" width=\"360\" height=\"12\" fill=\"url(#fl-scale)\" stroke=\"#222\"/>",
                     FormatFixed(bar_top, 1));
  out += fmt::format(
      "<text x=\"140\" y=\"{0}\" text-anchor=\"middle\">−{1}</text><text x=\"320\" y=\"{0}\" "
      "text-anchor=\"middle\">0</text><text x=\"500\" y=\"{0}\" text-anchor=\"middle\">+{1}</text>"
      "<text x=\"320\" y=\"{2}\" text-anchor=\"middle\" class=\"axis\">{3} (µm)</text>\n",
      FormatFixed(bar_top + 28, 1), Readable(max_abs), FormatFixed(bar_top + 48, 1), Esc(mesh.names.front()));
  return out + "</svg>\n";
}

// The colour bar under the canvas: the maps' gradient with ticks, in µm.
std::string ScaleBar(double max_abs) {
  const double range = max_abs > 0 ? max_abs : 1;
  std::string out =
      "<svg class=\"scalebar\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 460 46\" width=\"460\" "
      "height=\"46\" role=\"img\"><title>Colour scale of the 3-D view and the maps</title>"
      "<rect x=\"20\" y=\"4\" width=\"360\" height=\"12\" fill=\"url(#fl-scale)\" stroke=\"#222\"/>";
  const std::vector<double> ticks = NiceTicks(-range, range, 5);
  const double step = ticks.size() > 1 ? ticks[1] - ticks[0] : 1;
  for (double t : ticks) {
    const double x = 20 + (t + range) / (2 * range) * 360;
    out +=
        fmt::format("<text x=\"{}\" y=\"34\" text-anchor=\"middle\">{}</text>", FormatFixed(x, 1), TickLabel(t, step));
  }
  return out + "<text x=\"392\" y=\"15\">µm</text></svg>\n";
}

constexpr const char* kViewScript = R"JS(
(function () {
  var root = document.getElementById("view3d");
  var data = JSON.parse(document.getElementById("view3d-data").textContent);
  var stage = root.querySelector(".stage"), canvas = stage.querySelector("canvas"), tip = stage.querySelector(".tip");
  function fallback(why) {
    stage.style.display = "none";
    root.querySelector(".controls").style.display = "none";
    root.querySelector(".print-only").style.display = "block";
    root.querySelector(".why").textContent = why;
    document.body.dataset.view3d = "fallback: " + why;
  }
  if (!window.THREE) { fallback("three.js did not load"); return; }
  var renderer;
  try {
    renderer = new THREE.WebGLRenderer({canvas: canvas, antialias: true, preserveDrawingBuffer: true});
  } catch (e) { fallback("this browser has no WebGL"); return; }
  renderer.setClearColor(0xfafafa, 1);
  var scene = new THREE.Scene();
  var cx = data.x0 + data.nx * data.dx / 2, cy = data.y0 + data.ny * data.dy / 2, zs = [], zmid = 0;
  data.z.forEach(function (z) { if (z !== null) zs.push(z); });
  zs.sort(function (a, b) { return a - b; });
  zmid = zs.length ? zs[zs.length >> 1] : 0;
  var span = Math.max(data.nx * data.dx, data.ny * data.dy);
  function colourOf(v) {
    if (v === null || !isFinite(v)) return new THREE.Color(0xf0f0f0);
    var t = Math.max(-1, Math.min(1, v / data.scale));
    return new THREE.Color(data.lut[Math.round((t + 1) * 32)]);
  }
  // The surface: one vertex per grid node, two triangles per cell whose four nodes are drawn.
  var n = data.nx * data.ny, pos = new Float32Array(3 * n), col = new Float32Array(3 * n), index = [];
  for (var j = 0; j < data.ny; ++j) for (var i = 0; i < data.nx; ++i) {
    var k = j * data.nx + i, z = data.z[k];
    pos[3 * k] = data.x0 + (i + 0.5) * data.dx - cx; pos[3 * k + 1] = data.y0 + (j + 0.5) * data.dy - cy;
    pos[3 * k + 2] = (z === null ? 0 : z - zmid);
  }
  for (var j2 = 0; j2 + 1 < data.ny; ++j2) for (var i2 = 0; i2 + 1 < data.nx; ++i2) {
    var a = j2 * data.nx + i2, b = a + 1, c = a + data.nx, d = c + 1;
    if (data.z[a] === null || data.z[b] === null || data.z[c] === null || data.z[d] === null) continue;
    index.push(a, b, d, a, d, c);
  }
  var geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(pos, 3));
  geometry.setAttribute("color", new THREE.BufferAttribute(col, 3));
  geometry.setIndex(index);
  geometry.computeVertexNormals();
  var material = new THREE.MeshLambertMaterial({vertexColors: THREE.VertexColors, side: THREE.DoubleSide});
  scene.add(new THREE.Mesh(geometry, material));
  scene.add(new THREE.AmbientLight(0xffffff, 0.7));
  var sun = new THREE.DirectionalLight(0xffffff, 0.45); sun.position.set(-1, -2, 3); scene.add(sun);
  function showField(f) {
    var values = data.fields[f].values;
    for (var k = 0; k < n; ++k) { var c = colourOf(values[k]); col[3 * k] = c.r; col[3 * k + 1] = c.g; col[3 * k + 2] = c.b; }
    geometry.attributes.color.needsUpdate = true;
  }
  // Probe points of each loop, coloured by their measured deviation.
  var clouds = data.points.map(function (p) {
    var g = new THREE.BufferGeometry(), m = p.dev.length, xyz = new Float32Array(3 * m), rgb = new Float32Array(3 * m);
    for (var q = 0; q < m; ++q) {
      xyz[3 * q] = p.xyz[3 * q] - cx; xyz[3 * q + 1] = p.xyz[3 * q + 1] - cy; xyz[3 * q + 2] = p.xyz[3 * q + 2] - zmid + span * 0.002;
      var c = colourOf(p.dev[q]); rgb[3 * q] = c.r; rgb[3 * q + 1] = c.g; rgb[3 * q + 2] = c.b;
    }
    g.setAttribute("position", new THREE.BufferAttribute(xyz, 3));
    g.setAttribute("color", new THREE.BufferAttribute(rgb, 3));
    var cloud = new THREE.Points(g, new THREE.PointsMaterial({size: 5, sizeAttenuation: false, vertexColors: THREE.VertexColors}));
    cloud.userData = p; cloud.visible = false; scene.add(cloud);
    return cloud;
  });
  var path = null;
  if (data.path.length >= 6) {
    var seg = [];
    for (var s = 1; s < data.pass.length; ++s) if (data.pass[s] === data.pass[s - 1]) {
      for (var e = -1; e <= 0; ++e) seg.push(data.path[3 * (s + e)] - cx, data.path[3 * (s + e) + 1] - cy, data.path[3 * (s + e) + 2] - zmid + span * 0.001);
    }
    var pg = new THREE.BufferGeometry();
    pg.setAttribute("position", new THREE.BufferAttribute(new Float32Array(seg), 3));
    path = new THREE.LineSegments(pg, new THREE.LineBasicMaterial({color: 0x333333, transparent: true, opacity: 0.5}));
    path.visible = false; scene.add(path);
  }
  var camera = new THREE.PerspectiveCamera(35, 4 / 3, span / 100, span * 20);
  camera.up.set(0, 0, 1);
  camera.position.set(-0.75 * span, -1.2 * span, 0.9 * span);
  camera.lookAt(0, 0, 0);
  var controls = THREE.OrbitControls ? new THREE.OrbitControls(camera, canvas) : null;
  function render() { renderer.render(scene, camera); }
  function resize() {
    var w = stage.clientWidth, h = stage.clientHeight;
    renderer.setPixelRatio(window.devicePixelRatio || 1); renderer.setSize(w, h, false);
    camera.aspect = w / h; camera.updateProjectionMatrix(); render();
  }
  if (controls) controls.addEventListener("change", render);
  window.addEventListener("resize", resize);
  var select = root.querySelector("select.field"), loopSelect = root.querySelector("select.points");
  select.addEventListener("change", function () { showField(+select.value); render(); });
  loopSelect.addEventListener("change", function () {
    clouds.forEach(function (c, q) { c.visible = String(q) === loopSelect.value; }); render();
  });
  var pathBox = root.querySelector("input.path");
  if (!path) pathBox.disabled = true;
  pathBox.addEventListener("change", function () { if (path) path.visible = pathBox.checked; render(); });
  var ray = new THREE.Raycaster(), mouse = new THREE.Vector2();
  canvas.addEventListener("mousemove", function (ev) {
    var shown = clouds.filter(function (c) { return c.visible; });
    if (!shown.length) { tip.style.display = "none"; return; }
    var r = canvas.getBoundingClientRect();
    mouse.set((ev.clientX - r.left) / r.width * 2 - 1, -(ev.clientY - r.top) / r.height * 2 + 1);
    ray.params.Points.threshold = span / 150;
    ray.setFromCamera(mouse, camera);
    var hit = ray.intersectObjects(shown)[0];
    if (!hit) { tip.style.display = "none"; return; }
    var p = hit.object.userData, q = hit.index;
    tip.textContent = "loop " + p.loop + ": x " + p.xyz[3 * q].toFixed(2) + ", y " + p.xyz[3 * q + 1].toFixed(2) +
      " mm; deviation " + p.dev[q].toFixed(2) + " µm";
    tip.style.left = (ev.clientX - r.left + 12) + "px"; tip.style.top = (ev.clientY - r.top + 12) + "px";
    tip.style.display = "block";
  });
  showField(0);
  resize();
  // For headless checks: the share of the canvas that is not background.
  var probe = document.createElement("canvas"); probe.width = 64; probe.height = 48;
  var ctx = probe.getContext("2d"); ctx.drawImage(canvas, 0, 0, 64, 48);
  var px = ctx.getImageData(0, 0, 64, 48).data, drawn = 0;
  for (var t = 0; t < px.length; t += 4) if (Math.abs(px[t] - 250) + Math.abs(px[t + 1] - 250) + Math.abs(px[t + 2] - 250) > 12) ++drawn;
  document.body.dataset.view3d = "drawn " + Math.round(100 * drawn / (64 * 48)) + "%";
})();
)JS";

}  // namespace

Status View3dSection(std::string& html, const RunData& run, double max_abs_um) {
  OpenSection(html, "view3d", "The part in 3-D",
              "The machined surface coloured by deviation on the report's one scale (red = material left, blue = "
              "removed beyond nominal). Drag to turn, scroll to zoom, right-drag to pan; pick a loop's probe points "
              "to read their values on hover.");
  if (run.loops.empty() || !run.loops.front().points) {
    NotAvailable(html, "3-D view", "loop 0 has no deviations");
    CloseSection(html);
    return Status::Ok();
  }
  const Mesh mesh = BuildMesh(run);
  if (mesh.fields.empty()) {
    NotAvailable(html, "3-D view", "no loop's points cover loop 0's area");
    CloseSection(html);
    return Status::Ok();
  }
  const Result<std::string> three = ReadPackageScript("three.min.js");
  const Result<std::string> orbit = ReadPackageScript("examples/js/controls/OrbitControls.js");
  if (!three.ok() || !orbit.ok()) {
    // The run's programs and analysis do not depend on a viewer: without three.js the section shows the
    // static projection (the print view) and says why, and the log warns once.
    const Status& missing = !three.ok() ? three.status() : orbit.status();
    log::Warn("report: {}; the 3-D section shows the static view only", missing.message());
    NotAvailable(html, "interactive 3-D view", missing.message());
    html += ScaleBar(max_abs_um);
    html += FigureHtml(ProjectionSvg(mesh, max_abs_um),
                       "Static view of the part: " + mesh.names.front() + ", seen from the front left.");
    CloseSection(html);
    return Status::Ok();
  }
  html += "<div class=\"controls\"><label>Colour: <select class=\"field\">";
  for (std::size_t f = 0; f < mesh.names.size(); ++f) {
    html += fmt::format("<option value=\"{}\">{}</option>", f, Esc(mesh.names[f]));
  }
  html += "</select></label><label>Probe points: <select class=\"points\"><option value=\"-1\">hidden</option>";
  int shown = 0;
  for (const LoopData& loop : run.loops) {
    if (loop.points) html += fmt::format("<option value=\"{}\">loop {}</option>", shown++, loop.loop);
  }
  html += "</select></label><label><input type=\"checkbox\" class=\"path\"> tool path</label></div>\n";
  html += "<div class=\"stage\"><canvas width=\"800\" height=\"600\"></canvas><div class=\"tip\"></div></div>\n";
  html += ScaleBar(max_abs_um);
  html += "<div class=\"print-only\"><p class=\"na why\"></p>" +
          FigureHtml(ProjectionSvg(mesh, max_abs_um),
                     "Static view of the part for print: " + mesh.names.front() + ", seen from the front left.") +
          "</div>\n";
  html += "<script type=\"application/json\" id=\"view3d-data\">" + DataJson(run, mesh, max_abs_um) + "</script>\n";
  html += "<script>/* three.js r111, Debian libjs-three, MIT licence */\n" + *three + "\n</script>\n";
  html += "<script>/* OrbitControls, Debian libjs-three, MIT licence */\n" + *orbit + "\n</script>\n";
  html += "<script>" + std::string(kViewScript) + "</script>\n";
  CloseSection(html);
  return Status::Ok();
}

}  // namespace formloop::app::report
