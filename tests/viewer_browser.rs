//! The generated `view.html` in a real browser: headless Chromium (the Debian package
//! `chromium`, driven over the DevTools protocol by the `headless_chrome` crate) loads the page
//! from a `file://` URL, the test takes screenshots and checks that both meshes are drawn and
//! that a real mouse click on the scan selects a vertex and marks its match on the reference.
//!
//! Without Chromium the test says SKIPPED, or fails under `CI=true` (`.ci/run` installs it).

use std::{
    ffi::OsStr,
    path::PathBuf,
    time::{Duration, Instant},
};

use headless_chrome::{
    browser::tab::point::Point, protocol::cdp::Page::CaptureScreenshotFormatOption, Browser, LaunchOptions,
    Tab,
};
use shapeforest::{
    synth::{creature_family, CreatureParams},
    viz::{view_html, PointErrors, ViewPair},
};

const BACKGROUND: [u8; 3] = [246, 246, 246];
const MARKER: [u8; 3] = [255, 0, 255];

fn chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("SHAPEFOREST_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    ["/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome"]
        .iter()
        .map(PathBuf::from)
        .find(|p| p.is_file())
}

struct Shot {
    width: usize,
    height: usize,
    rgb: Vec<u8>,
}

impl Shot {
    /// Takes a screenshot; with `SHAPEFOREST_SCREENSHOTS=DIR` it is also saved as DIR/NAME.png.
    fn take(tab: &Tab, name: &str) -> Shot {
        let bytes =
            tab.capture_screenshot(CaptureScreenshotFormatOption::Png, None, None, true).expect("screenshot");
        if let Some(dir) = std::env::var_os("SHAPEFOREST_SCREENSHOTS") {
            let _ = std::fs::write(PathBuf::from(dir).join(format!("{name}.png")), &bytes);
        }
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = decoder.read_info().expect("png header");
        let mut buf = vec![0; reader.output_buffer_size().expect("png size")];
        let info = reader.next_frame(&mut buf).expect("png frame");
        let channels = info.color_type.samples();
        let rgb = buf[..info.buffer_size()].chunks(channels).flat_map(|p| [p[0], p[1], p[2]]).collect();
        Shot { width: info.width as usize, height: info.height as usize, rgb }
    }

    fn count(&self, x0: usize, x1: usize, y0: usize, pred: impl Fn([u8; 3]) -> bool) -> usize {
        let mut n = 0;
        for y in y0..self.height {
            for x in x0..x1 {
                let i = 3 * (y * self.width + x);
                if pred([self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]) {
                    n += 1;
                }
            }
        }
        n
    }
}

fn eval_json(tab: &Tab, js: &str) -> serde_json::Value {
    let r = tab.evaluate(js, false).unwrap_or_else(|e| panic!("evaluating {js}: {e}"));
    let text = r.value.and_then(|v| v.as_str().map(str::to_string)).unwrap_or_else(|| "null".into());
    serde_json::from_str(&text).unwrap_or(serde_json::Value::Null)
}

#[test]
fn view_html_draws_both_meshes_and_a_click_selects_a_vertex_and_its_match() {
    let Some(chrome) = chromium() else {
        let msg = "Chromium is missing (Debian package `chromium`, or set SHAPEFOREST_CHROMIUM): \
                   the browser test of view.html cannot run";
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            panic!("{msg}");
        }
        println!("SKIPPED: {msg}");
        return;
    };
    // Two poses of the synthetic creature (shared indexing); the map is the ground truth.
    let fam =
        creature_family(&CreatureParams { target_vertices: 2000, seed: 3, ..Default::default() }, 2).unwrap();
    let (scan, reference) = (&fam.shapes[1], &fam.shapes[0]);
    let map: Vec<usize> = (0..scan.n_vertices()).collect();
    let evaluated: Vec<usize> = (0..scan.n_vertices()).step_by(10).collect();
    let errors = vec![0.01; evaluated.len()];
    let pair = ViewPair {
        scan,
        scan_name: "creature1",
        reference,
        reference_name: "creature0",
        map: &map,
        errors: Some(PointErrors { vertices: &evaluated, errors: &errors }),
    };
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("view.html");
    std::fs::write(&page, view_html(&pair, "creature1 → creature0").unwrap()).unwrap();
    let profile = dir.path().join("profile");
    std::fs::create_dir_all(&profile).unwrap();

    let args: Vec<&OsStr> = [
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--disable-quic",
        "--disable-component-update",
        "--hide-scrollbars",
    ]
    .iter()
    .map(OsStr::new)
    .collect();
    let options = LaunchOptions {
        headless: true,
        sandbox: false,
        enable_gpu: true, // no --disable-gpu: WebGL runs on SwiftShader (software)
        path: Some(chrome.clone()),
        window_size: Some((1200, 700)),
        user_data_dir: Some(profile),
        args,
        idle_browser_timeout: Duration::from_secs(120),
        ..Default::default()
    };
    let browser = Browser::new(options).unwrap_or_else(|e| panic!("cannot start {}: {e}", chrome.display()));
    let tab = browser.new_tab().unwrap();
    tab.navigate_to(&format!("file://{}", page.display())).unwrap().wait_until_navigated().unwrap();

    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let state = eval_json(
            &tab,
            "JSON.stringify({ready: !!(window.sfView && window.sfView.ready), status: document.getElementById('status').textContent})",
        );
        if state["ready"] == true {
            break;
        }
        assert!(Instant::now() < deadline, "view.html did not become ready: {state}");
        std::thread::sleep(Duration::from_millis(200));
    }

    // Both halves show a mesh: many pixels differ from the background below the title bar,
    // and they are coloured (not grey).
    let shot = Shot::take(&tab, "loaded");
    let half = shot.width / 2;
    let top = 90;
    let coloured = |p: [u8; 3]| {
        let (lo, hi) = (p.iter().min().unwrap(), p.iter().max().unwrap());
        p != BACKGROUND && hi - lo > 25
    };
    let (left, right) = (shot.count(0, half, top, coloured), shot.count(half, shot.width, top, coloured));
    let area = half * (shot.height - top);
    assert!(
        left * 50 > area && right * 50 > area,
        "coloured pixels: left {left}, right {right} of {area} each"
    );

    // A real click (DevTools mouse events) on a visible scan vertex selects it and its match.
    let target = eval_json(
        &tab,
        "(() => { for (let v = 0; v < 3000; v += 13) { const p = sfView.project('scan', v); \
         if (p) return JSON.stringify({v, x: p.x, y: p.y}); } return null; })()",
    );
    let (x, y) = (target["x"].as_f64().expect("a visible scan vertex"), target["y"].as_f64().unwrap());
    tab.click_point(Point { x, y }).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let sel = eval_json(&tab, "JSON.stringify(sfView.selection)");
    assert_eq!(sel["side"], "scan", "selection after the click: {sel}");
    let scan_v = sel["scanVertex"].as_u64().expect("scan vertex") as usize;
    let ref_v = sel["referenceVertex"].as_u64().expect("reference vertex") as usize;
    assert_eq!(ref_v, map[scan_v], "the marked reference vertex is the scan vertex's match");
    let v = target["v"].as_u64().unwrap() as usize;
    let d: f64 = (0..3).map(|a| (scan.vertices[scan_v][a] - scan.vertices[v][a]).powi(2)).sum::<f64>().sqrt();
    let (lo, hi) = scan.bounding_box();
    let diag: f64 = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
    assert!(d < 0.05 * diag, "clicked near vertex {v}, selected {scan_v} at {d:.4} (diagonal {diag:.3})");
    let text = eval_json(&tab, "JSON.stringify(document.getElementById('selection').textContent)");
    assert!(text.as_str().unwrap_or_default().contains(&format!("vertex {scan_v}")), "{text}");

    // Both markers are drawn, one in each half.
    let shot = Shot::take(&tab, "selected");
    let is_marker = |p: [u8; 3]| p.iter().zip(MARKER).all(|(a, b)| a.abs_diff(b) < 40);
    let (ml, mr) = (shot.count(0, half, top, is_marker), shot.count(half, shot.width, top, is_marker));
    assert!(ml > 10 && mr > 10, "marker pixels: left {ml}, right {mr}");
}
