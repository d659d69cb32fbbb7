//! `awl info PATH`: the first thing a user runs on a scan folder or a cloud/mesh file.

use std::path::{Path, PathBuf};

use anyhow::Context;
use awl::cloud::Bounds;
use awl::io::scan::{load_view, read_scan};
use awl::io::{Loaded, extension, mesh};
use awl::scan::{ViewData, ViewPose};
use serde_json::json;

/// Arguments of `awl info`.
#[derive(clap::Args)]
pub struct InfoArgs {
    /// A scan folder (with scan.json), or a .ply / .pcd cloud, or a .stl / .obj / .ply mesh.
    pub path: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

fn bounds_json(b: Option<Bounds>) -> serde_json::Value {
    match b {
        Some(b) => json!({ "min": [b.min.x, b.min.y, b.min.z], "max": [b.max.x, b.max.y, b.max.z] }),
        None => serde_json::Value::Null,
    }
}

fn bounds_text(b: Option<Bounds>) -> String {
    match b {
        Some(b) => format!(
            "x [{:.3}, {:.3}]  y [{:.3}, {:.3}]  z [{:.3}, {:.3}] m  (extent {:.3} x {:.3} x {:.3} m)",
            b.min.x,
            b.max.x,
            b.min.y,
            b.max.y,
            b.min.z,
            b.max.z,
            b.extent().x,
            b.extent().y,
            b.extent().z
        ),
        None => "empty".into(),
    }
}

fn scan_info(dir: &Path) -> anyhow::Result<serde_json::Value> {
    let scan = read_scan(dir)?;
    let rays = scan.camera.map(|c| c.intrinsics.ray_table());
    let mut views = Vec::new();
    let mut warnings = scan.warnings.clone();
    let mut world = awl::PointCloud::default();
    for (i, view) in scan.views.iter().enumerate() {
        let loaded = load_view(&scan, i, rays.as_deref()).with_context(|| format!("view {i}"))?;
        warnings.extend(loaded.warnings.iter().map(|w| format!("view {i}: {w}")));
        let cloud_world = loaded.cloud_camera.transformed(&loaded.world_from_camera);
        let (kind, file) = match &view.data {
            ViewData::Depth { depth, color } => (if color.is_some() { "depth+color" } else { "depth" }, Some(depth)),
            ViewData::Points { points } => ("points", Some(points)),
            ViewData::Images { .. } => ("images in memory", None),
        };
        let pose = match view.pose {
            ViewPose::Camera { .. } => "T_world_camera",
            ViewPose::Chain { .. } => "T_world_base*T_base_ee*T_ee_camera",
        };
        let t = loaded.world_from_camera.translation.vector;
        views.push(json!({
            "index": i, "kind": kind, "file": file, "pose": pose, "points": cloud_world.len(),
            "camera_position_world": [t.x, t.y, t.z], "bounds_world": bounds_json(cloud_world.bounds()),
        }));
        world.extend(&cloud_world);
    }
    Ok(json!({
        "type": "scan", "path": dir, "views": views, "points": world.len(),
        "camera": scan.camera.map(|c| json!({
            "width": c.intrinsics.width, "height": c.intrinsics.height, "fx": c.intrinsics.fx, "fy": c.intrinsics.fy,
            "cx": c.intrinsics.cx, "cy": c.intrinsics.cy, "depth_scale": c.depth_scale,
            "depth_min": c.depth_min_m, "depth_max": if c.depth_max_m.is_finite() { json!(c.depth_max_m) } else { json!(null) },
        })),
        "tag": scan.tag.map(|t| json!({ "family": t.family, "id": t.id, "size": t.size_m })),
        "hand_eye": scan.ee_from_camera.is_some(),
        "truth": dir.join("truth.json").is_file(),
        "bounds_world": bounds_json(world.bounds()),
        "warnings": warnings,
    }))
}

fn file_info(path: &Path) -> anyhow::Result<serde_json::Value> {
    let ext = extension(path);
    if ext == "stl" || ext == "obj" {
        let Loaded { value: m, warnings } = mesh::read_mesh_checked(path)?;
        let cloud = awl::PointCloud::from_points(m.vertices.iter().map(|v| v.cast::<f32>()).collect());
        return Ok(json!({ "type": "mesh", "path": path, "vertices": m.vertices.len(), "triangles": m.triangles.len(),
                          "area_m2": m.area(), "bounds": bounds_json(cloud.bounds()), "warnings": warnings }));
    }
    // (points with a NaN or infinite coordinate dropped, with a warning: the bounds are the finite points')
    let Loaded { value: cloud, warnings } = mesh::read_cloud_checked(path)?;
    let mut info = json!({ "type": "cloud", "path": path, "points": cloud.len(), "normals": cloud.normals.is_some(),
                           "colors": cloud.colors.is_some(), "bounds": bounds_json(cloud.bounds()),
                           "warnings": warnings });
    if ext == "ply"
        && let Ok(m) = awl::io::ply::read_ply_mesh(path)
        && !m.triangles.is_empty()
    {
        info["triangles"] = json!(m.triangles.len());
        info["area_m2"] = json!(m.area());
    }
    Ok(info)
}

fn print_text(info: &serde_json::Value) {
    let bounds = |v: &serde_json::Value| -> Option<Bounds> {
        let p = |k: &str| -> Option<nalgebra::Point3<f32>> {
            let a = v.get(k)?.as_array()?;
            Some(nalgebra::Point3::new(a[0].as_f64()? as f32, a[1].as_f64()? as f32, a[2].as_f64()? as f32))
        };
        Some(Bounds { min: p("min")?, max: p("max")? })
    };
    println!("{}: {}", info["type"].as_str().unwrap_or("?"), info["path"].as_str().unwrap_or("?"));
    if info["type"] == "scan" {
        println!("  camera: {}", info["camera"]);
        println!("  tag: {}   hand-eye T_ee_camera: {}   truth.json: {}", info["tag"], info["hand_eye"], info["truth"]);
        for v in info["views"].as_array().into_iter().flatten() {
            println!(
                "  view {:>3}: {:<11} {:>8} points  pose {}  ({})",
                v["index"],
                v["kind"].as_str().unwrap_or(""),
                v["points"],
                v["pose"].as_str().unwrap_or(""),
                v["file"].as_str().unwrap_or("")
            );
        }
        println!("  total: {} points in {} views", info["points"], info["views"].as_array().map_or(0, Vec::len));
        println!("  bounds (world, seed poses): {}", bounds_text(bounds(&info["bounds_world"])));
    } else {
        for key in ["points", "normals", "colors", "vertices", "triangles", "area_m2"] {
            if !info[key].is_null() {
                println!("  {key}: {}", info[key]);
            }
        }
        println!("  bounds: {}", bounds_text(bounds(&info["bounds"])));
    }
}

/// Runs `awl info`.
pub fn run(args: &InfoArgs) -> anyhow::Result<()> {
    let path = &args.path;
    if !path.exists() {
        anyhow::bail!("{}: no such file or folder", path.display());
    }
    let info = if path.is_dir() { scan_info(path)? } else { file_info(path)? };
    for w in info["warnings"].as_array().into_iter().flatten() {
        eprintln!("warning: {}", w.as_str().unwrap_or_default());
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
    } else {
        print_text(&info);
    }
    Ok(())
}
