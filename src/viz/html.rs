//! `view.html` (three.js, inlined) and the evaluation's `index.html`.

use std::fmt::Write as _;

use base64::{engine::general_purpose::STANDARD as B64, Engine as _};

use super::{ViewPair, VizError};
use crate::eval::{cumulative_curve, ErrorSummary};
use crate::mesh::Mesh;

/// three.js r170, `build/three.module.min.js` of the npm package (MIT; see vendor/).
const THREE_JS: &str = include_str!("vendor/three.module.min.js");
/// `examples/jsm/controls/OrbitControls.js` of the same package.
const ORBIT_CONTROLS_JS: &str = include_str!("vendor/OrbitControls.js");
/// three.js's licence, copied into every page that embeds it.
const THREE_LICENSE: &str = include_str!("vendor/three-LICENSE");
/// The viewer's own script (orbit, colour modes, picking).
const VIEW_JS: &str = include_str!("view.js");

/// Errors above this (in √area units) get the heat map's last colour.
const ERROR_COLOR_MAX: f64 = 0.1;

/// Escapes text for HTML element content and attribute values.
fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

fn b64_f32(values: impl Iterator<Item = f32>) -> String {
    let bytes: Vec<u8> = values.flat_map(f32::to_le_bytes).collect();
    B64.encode(bytes)
}

fn b64_u32(values: impl Iterator<Item = usize>) -> String {
    let bytes: Vec<u8> = values.flat_map(|v| (v as u32).to_le_bytes()).collect();
    B64.encode(bytes)
}

fn shape_json(name: &str, mesh: &Mesh, colors: &[[u8; 3]]) -> serde_json::Value {
    serde_json::json!({
        "name": name,
        "positions": b64_f32(mesh.vertices.iter().flatten().map(|&x| x as f32)),
        "faces": b64_u32(mesh.faces.iter().flatten().copied()),
        "colors": B64.encode(colors.iter().flatten().copied().collect::<Vec<u8>>()),
    })
}

/// A cumulative error curve as an inline SVG (fraction of points within each error threshold,
/// thresholds 0 to 0.25).
fn curve_svg(errors: &[f64]) -> String {
    let (w, h, pad) = (280.0, 130.0, 34.0);
    let curve = cumulative_curve(errors, 50);
    let max_t = curve.thresholds.last().copied().unwrap_or(0.25).max(1e-9);
    let pts: Vec<String> = curve
        .thresholds
        .iter()
        .zip(&curve.fractions)
        .map(|(t, f)| {
            format!("{:.1},{:.1}", pad + t / max_t * (w - 2.0 * pad), h - pad - f * (h - 2.0 * pad))
        })
        .collect();
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" class=\"curve\">\
         <rect x=\"{pad}\" y=\"{pad}\" width=\"{}\" height=\"{}\" fill=\"#fff\" stroke=\"#999\"/>",
        w - 2.0 * pad,
        h - 2.0 * pad
    );
    let x05 = pad + 0.05 / max_t * (w - 2.0 * pad);
    let _ = write!(
        s,
        "<line x1=\"{x05:.1}\" y1=\"{pad}\" x2=\"{x05:.1}\" y2=\"{}\" stroke=\"#bbb\" stroke-dasharray=\"3,3\"/>\
         <polyline fill=\"none\" stroke=\"#c03030\" stroke-width=\"2\" points=\"{}\"/>\
         <text x=\"{pad}\" y=\"{}\" font-size=\"11\">0</text>\
         <text x=\"{:.1}\" y=\"{}\" font-size=\"11\" text-anchor=\"end\">{max_t:.2}</text>\
         <text x=\"{x05:.1}\" y=\"{}\" font-size=\"11\" text-anchor=\"middle\">0.05</text>\
         <text x=\"{}\" y=\"{}\" font-size=\"11\" text-anchor=\"end\">100%</text>\
         <text x=\"{}\" y=\"{}\" font-size=\"11\" text-anchor=\"middle\">geodesic error / √area</text></svg>",
        h - pad,
        pts.join(" "),
        h - pad + 14.0,
        w - pad,
        h - pad + 14.0,
        h - pad + 14.0,
        pad - 3.0,
        pad + 10.0,
        w / 2.0,
        h - 3.0,
    );
    s
}

/// The interactive page of one pair: both meshes in WebGL (three.js, inlined with its
/// licence), scan left and reference right, coloured through the map; drag to orbit, wheel to
/// zoom, click a point to mark it and its match. With errors: a heat-map mode (each vertex
/// shows the error of its nearest evaluated point) and the cumulative curve.
///
/// The page needs no network: three.js is inlined as `data:` modules behind an import map.
/// `window.sfView` exposes `ready`, `selection`, `select(side, vertex)` and
/// `project(side, vertex)` for scripts and tests.
///
/// ```
/// use shapeforest::{synth::icosphere, viz::{view_html, ViewPair}};
/// let s = icosphere(1, 1.0);
/// let map: Vec<usize> = (0..s.n_vertices()).collect();
/// let pair = ViewPair::new(&s, "a", &s, "b", &map);
/// let html = view_html(&pair, "a → b").unwrap();
/// assert!(html.contains("<canvas") && html.contains("three.js authors"));
/// ```
pub fn view_html(pair: &ViewPair<'_>, title: &str) -> Result<String, VizError> {
    pair.check()?;
    let (ref_colors, scan_colors) = pair.map_colors();
    let vertex_errors = pair.vertex_errors();
    let mut panel = String::new();
    let errors_json = match (&pair.errors, &vertex_errors) {
        (Some(e), Some(per_vertex)) => {
            let s = ErrorSummary::of(e.errors);
            let _ = write!(
                panel,
                "<div id=\"errors\"><div><b>{} evaluated points</b><br>{:.1} % within 0.05<br>{:.1} % within 0.10<br>\
                 mean {:.4}</div>{}<div><div>heat map: error of the nearest evaluated point</div><div class=\"legend\">\
                 <span>0</span><span class=\"bar\"></span><span>≥ {ERROR_COLOR_MAX}</span></div></div></div>",
                e.errors.len(),
                100.0 * s.within_005,
                100.0 * s.within_010,
                s.mean,
                curve_svg(e.errors)
            );
            serde_json::json!({
                "values": b64_f32(per_vertex.iter().map(|&x| x as f32)),
                "max": ERROR_COLOR_MAX,
            })
        }
        _ => serde_json::Value::Null,
    };
    let data = serde_json::json!({
        "scan": shape_json(pair.scan_name, pair.scan, &scan_colors),
        "reference": shape_json(pair.reference_name, pair.reference, &ref_colors),
        "map": b64_u32(pair.map.iter().copied()),
        "errors": errors_json,
    });
    // `</` cannot appear inside a <script> element; JSON allows `\/`.
    let data = data.to_string().replace("</", "<\\/");
    let import_map = serde_json::json!({
        "imports": {
            "three": format!("data:text/javascript;base64,{}", B64.encode(THREE_JS)),
            "three/addons/controls/OrbitControls.js":
                format!("data:text/javascript;base64,{}", B64.encode(ORBIT_CONTROLS_JS)),
        }
    });
    let error_button =
        if pair.errors.is_some() { "<button data-mode=\"error\">error heat map</button>" } else { "" };
    let mut page = String::with_capacity(data.len() + 1_100_000);
    let _ = write!(
        page,
        r#"<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<!-- Generated by shapeforest {version}. Embeds three.js r170 (https://threejs.org), under its licence:
{license}-->
<style>
html, body {{ margin: 0; height: 100%; font: 14px system-ui, sans-serif; background: #f6f6f6; color: #222; }}
body {{ display: flex; flex-direction: column; }}
#bar {{ padding: 6px 10px; background: #fff; border-bottom: 1px solid #ddd; }}
#bar button {{ margin-left: 6px; }} #bar button.on {{ font-weight: bold; }}
#stage {{ position: relative; flex: 1; min-height: 0; }}
#names {{ position: absolute; top: 6px; left: 0; right: 0; display: flex; pointer-events: none; }}
#names div {{ flex: 1; text-align: center; color: #555; }}
#view {{ display: block; width: 100%; height: 100%; }}
#errors {{ display: flex; align-items: center; gap: 16px; padding: 4px 10px; background: #fff; border-top: 1px solid #ddd; }}
.legend {{ display: flex; align-items: center; gap: 4px; }}
.legend .bar {{ width: 160px; height: 10px; background: linear-gradient(90deg, rgb(40,60,160), rgb(60,190,210), rgb(240,220,60), rgb(200,30,30)); }}
#status {{ position: absolute; top: 50%; width: 100%; text-align: center; }}
</style>
<script type="importmap">{import_map}</script>
</head>
<body>
<div id="bar"><b>{title}</b> · drag to orbit, wheel to zoom, click a point to see its match ·
colours: <button data-mode="map" class="on">through the map</button>{error_button}
<div id="selection">no point selected</div></div>
<div id="stage"><canvas id="view"></canvas>
<div id="names"><div>scan: {scan}</div><div>reference: {reference}</div></div>
<div id="status">loading…</div></div>
{panel}
<script id="sf-data" type="application/json">{data}</script>
<script type="module">
{script}
</script>
</body>
</html>
"#,
        title = esc(title),
        version = env!("CARGO_PKG_VERSION"),
        license = THREE_LICENSE.replace("--", "- -"),
        scan = esc(pair.scan_name),
        reference = esc(pair.reference_name),
        script = VIEW_JS,
    );
    Ok(page)
}

/// One test shape on the evaluation page.
#[derive(Clone, Debug)]
pub struct IndexShape {
    /// The shape's name.
    pub name: String,
    /// Path of its snapshot, relative to the page.
    pub snapshot: String,
    /// Path of its `view.html`, relative to the page.
    pub view: String,
    /// A line under the picture (e.g. the accuracy).
    pub caption: String,
}

/// The evaluation's overview page.
#[derive(Clone, Debug)]
pub struct IndexPage {
    /// Title.
    pub title: String,
    /// The results table as text (shown preformatted, as the CLI prints it).
    pub table: String,
    /// The cumulative curves as an SVG document (inlined).
    pub curves_svg: Option<String>,
    /// Files beside the page to link (`results.csv`, …).
    pub files: Vec<String>,
    /// One entry per test shape.
    pub shapes: Vec<IndexShape>,
}

/// The evaluation's `index.html`: the table, the curves and a snapshot per test shape, each
/// linking to its interactive view.
///
/// ```
/// use shapeforest::viz::{index_html, IndexPage};
/// let page = IndexPage { title: "cat".into(), table: "a | b".into(), curves_svg: None, files: vec![], shapes: vec![] };
/// assert!(index_html(&page).contains("<pre>a | b</pre>"));
/// ```
pub fn index_html(page: &IndexPage) -> String {
    let mut s = String::new();
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{t}</title>\n<style>\
         body {{ font: 14px system-ui, sans-serif; margin: 20px; color: #222; }} pre {{ background: #f4f4f4; padding: 8px; }}\
         .shapes {{ display: flex; flex-wrap: wrap; gap: 16px; }} .shape {{ width: 400px; }} .shape img {{ width: 400px; border: 1px solid #ddd; }}\
         </style>\n</head>\n<body>\n<h1>{t}</h1>\n<h2>Accuracy</h2>\n<pre>{table}</pre>\n",
        t = esc(&page.title),
        table = esc(&page.table)
    );
    if let Some(svg) = &page.curves_svg {
        let svg = svg.find("<svg").map_or(svg.as_str(), |i| &svg[i..]);
        let _ = write!(s, "<h2>Cumulative error curves</h2>\n<div class=\"curves\">{svg}</div>\n");
    }
    if !page.files.is_empty() {
        let links: Vec<String> =
            page.files.iter().map(|f| format!("<a href=\"{0}\">{0}</a>", esc(f))).collect();
        let _ = writeln!(s, "<p>Files: {}</p>", links.join(" · "));
    }
    if !page.shapes.is_empty() {
        s.push_str(
            "<h2>Test shapes</h2>\n<p>Scan (left) coloured through the regularised forest's map, reference \
             (right) coloured by its coordinates: where the map is right, matching parts share colours. \
             Click a picture for the interactive view with the error heat map.</p>\n<div class=\"shapes\">\n",
        );
        for sh in &page.shapes {
            let _ = writeln!(
                s,
                "<div class=\"shape\"><a href=\"{v}\"><img src=\"{p}\" alt=\"{n}\"></a><br><b>{n}</b> {c}</div>",
                v = esc(&sh.view),
                p = esc(&sh.snapshot),
                n = esc(&sh.name),
                c = esc(&sh.caption)
            );
        }
        s.push_str("</div>\n");
    }
    s.push_str("</body>\n</html>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;
    use crate::viz::PointErrors;

    #[test]
    fn the_page_embeds_three_its_licence_the_data_and_the_curve() {
        let s = icosphere(2, 1.0);
        let map: Vec<usize> = (0..s.n_vertices()).rev().collect();
        let vertices = [0, 5, 9];
        let errors = [0.0, 0.02, 0.2];
        let pair = ViewPair::new(&s, "scan</script>", &s, "ref", &map)
            .with_errors(PointErrors { vertices: &vertices, errors: &errors });
        let html = view_html(&pair, "t").unwrap();
        assert!(html.contains("SPDX-License-Identifier: MIT") || html.contains("The MIT License"));
        assert!(html.contains("data:text/javascript;base64,"));
        assert!(html.contains("66.7 % within 0.05"), "summary of the errors");
        assert!(html.contains("<polyline"));
        assert!(html.contains("error heat map"));
        // The name cannot close the data block early.
        assert_eq!(html.matches("</script>").count(), 3, "import map, data and module script only");
        assert!(!VIEW_JS.contains("</script"));
        // The per-vertex errors come from the nearest evaluated point.
        let per_vertex = pair.vertex_errors().unwrap();
        assert_eq!((per_vertex[0], per_vertex[5], per_vertex[9]), (0.0, 0.02, 0.2));
    }

    #[test]
    fn bad_errors_are_refused() {
        let s = icosphere(1, 1.0);
        let map: Vec<usize> = (0..s.n_vertices()).collect();
        let pair = ViewPair::new(&s, "a", &s, "b", &map)
            .with_errors(PointErrors { vertices: &[100], errors: &[0.1] });
        assert!(view_html(&pair, "x").unwrap_err().to_string().contains("evaluated vertex 100"));
    }
}
