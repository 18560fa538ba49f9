//! Scene resolution (directory layouts and explicit paths) and photographs: formats, 16-bit
//! precision, size checks, and lazy decoding.

use crate::common;

use scantex::camera::colmap::{self, Image, Reconstruction};
use scantex::camera::{Camera, CameraModel, Pose};
use scantex::io::image::PhotoPixels;
use scantex::scene::{PhotoStatus, Scene, SceneSpec};
use std::path::Path;

fn model(dir: &Path, names: &[&str]) {
    let mut rec = Reconstruction::default();
    rec.cameras.insert(
        1,
        Camera::new(
            1,
            CameraModel::SimpleRadial,
            32,
            16,
            vec![30.0, 16.0, 8.0, 0.01],
        )
        .unwrap(),
    );
    for (i, n) in names.iter().enumerate() {
        let id = i as u32 + 1;
        let pose = Pose::from_colmap([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 3.0]);
        rec.images.insert(
            id,
            Image {
                id,
                camera_id: 1,
                name: n.to_string(),
                pose,
                points2d: vec![],
            },
        );
    }
    colmap::write_text(&rec, dir).unwrap();
}

#[test]
fn directory_layouts_resolve() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path();
    std::fs::create_dir_all(root.join("images")).unwrap();
    std::fs::create_dir_all(root.join("masks")).unwrap();
    model(&root.join("sparse/0"), &["a.png"]);
    std::fs::write(root.join("scan.ply"), "").unwrap();
    let p = SceneSpec {
        dir: Some(root.into()),
        ..Default::default()
    }
    .resolve()
    .unwrap();
    assert_eq!(p.mesh.as_deref(), Some(root.join("scan.ply").as_path()));
    assert_eq!(p.colmap.as_deref(), Some(root.join("sparse/0").as_path()));
    assert_eq!(p.images.as_deref(), Some(root.join("images").as_path()));
    assert_eq!(p.masks.as_deref(), Some(root.join("masks").as_path()));
    // Explicit paths win; --colmap may name the scene folder itself.
    let other = tempfile::tempdir().unwrap();
    model(&other.path().join("sparse"), &["b.png"]);
    let p = SceneSpec {
        dir: Some(root.into()),
        colmap: Some(other.path().into()),
        mesh: Some("x.obj".into()),
        ..Default::default()
    }
    .resolve()
    .unwrap();
    assert_eq!(
        p.colmap.as_deref(),
        Some(other.path().join("sparse").as_path())
    );
    assert_eq!(p.mesh.as_deref(), Some(Path::new("x.obj")));
    // A folder as VisualSFM or OpenMVS leave it: its one camera file stands for sparse/.
    let vsfm = tempfile::tempdir().unwrap();
    std::fs::write(vsfm.path().join("model.nvm"), "NVM_V3\n0\n").unwrap();
    let found = |d: &Path| {
        SceneSpec {
            dir: Some(d.into()),
            ..Default::default()
        }
        .resolve()
    };
    assert_eq!(
        found(vsfm.path()).unwrap().colmap.as_deref(),
        Some(vsfm.path().join("model.nvm").as_path())
    );
    // Given without the folder, its images/ is still found beside it.
    std::fs::create_dir(vsfm.path().join("images")).unwrap();
    let p = SceneSpec {
        colmap: Some(vsfm.path().join("model.nvm")),
        ..Default::default()
    }
    .resolve()
    .unwrap();
    assert_eq!(
        p.images.as_deref(),
        Some(vsfm.path().join("images").as_path())
    );
    std::fs::write(vsfm.path().join("scene.mvs"), "").unwrap();
    let e = found(vsfm.path()).unwrap_err().to_string();
    assert!(
        e.contains("model.nvm, scene.mvs") && e.contains("--colmap"),
        "{e}"
    );
    // Two meshes: the user must choose.
    std::fs::write(root.join("other.obj"), "").unwrap();
    let e = SceneSpec {
        dir: Some(root.into()),
        ..Default::default()
    }
    .resolve()
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("other.obj") && e.contains("scan.ply") && e.contains("--mesh"),
        "{e}"
    );
}

#[test]
fn photos_in_every_format_decode_with_their_precision() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path();
    let names = ["a.png", "b16.png", "c.tif", "d.jpg", "e.png"];
    model(&root.join("sparse"), &names);
    std::fs::create_dir_all(root.join("images")).unwrap();
    std::fs::create_dir_all(root.join("masks")).unwrap();
    let img8 =
        image::RgbImage::from_fn(32, 16, |x, y| image::Rgb([x as u8 * 8, y as u8 * 16, 200]));
    img8.save(root.join("images/a.png")).unwrap();
    img8.save(root.join("images/c.tif")).unwrap();
    img8.save(root.join("images/d.jpg")).unwrap();
    // 16-bit values that 8 bits cannot hold.
    let img16 = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(32, 16, |x, _| {
        image::Rgb([1000 + x as u16, 0, 65535])
    });
    img16.save(root.join("images/b16.png")).unwrap();
    // A file whose header says 32x16 but whose pixel data is cut off: probing passes, decoding
    // fails. Shows Scene::load decodes nothing.
    let full = std::fs::read(root.join("images/a.png")).unwrap();
    std::fs::write(root.join("images/e.png"), &full[..full.len() / 2]).unwrap();
    // COLMAP's mask naming: <name>.png.
    image::GrayImage::new(32, 16)
        .save(root.join("masks/a.png.png"))
        .unwrap();

    let scene = Scene::load(&SceneSpec {
        dir: Some(root.into()),
        ..Default::default()
    })
    .unwrap();
    assert_eq!(scene.photos.len(), 5);
    for p in &scene.photos {
        assert_eq!(p.status(), PhotoStatus::Ok, "{}", p.name);
    }
    let by = |n: &str| scene.photos.iter().find(|p| p.name == n).unwrap();
    let a = by("a.png").load().unwrap();
    assert_eq!(
        a.get_pixel(3, 2).0,
        [24.0 / 255.0, 32.0 / 255.0, 200.0 / 255.0]
    );
    assert_eq!(by("c.tif").load().unwrap(), a);
    let j = by("d.jpg").load().unwrap();
    assert!((j.get_pixel(16, 8).0[2] - 200.0 / 255.0).abs() < 0.03);
    let b = by("b16.png").load().unwrap();
    assert!(
        (b.get_pixel(5, 0).0[0] - 1005.0 / 65535.0).abs() < 1e-6,
        "16-bit precision kept"
    );
    // Decoding into a previous photograph's buffer (larger, holding other values) keeps 8-bit
    // files 8-bit and reads the image crate's own conversion, 8- and 16-bit alike.
    for n in ["a.png", "d.jpg", "b16.png"] {
        let own = image::open(root.join("images").join(n))
            .unwrap()
            .into_rgb32f();
        let px = by(n).load_pixels(vec![7; 32 * 16 * 3 + 5]).unwrap();
        assert_eq!(matches!(px, PhotoPixels::Rgb8(_)), n != "b16.png", "{n}");
        assert_eq!(px.get(3, 2), own.get_pixel(3, 2).0, "{n}");
        assert_eq!(px.into_rgb32f(), own, "{n}");
    }
    assert!(by("e.png").load_pixels(vec![0; 16]).is_err());
    assert!(by("e.png").load().is_err());
    assert_eq!(
        by("a.png").load_mask().unwrap().unwrap().dimensions(),
        (32, 16)
    );
    assert!(by("b16.png").mask.is_none());
}

#[test]
fn statue_scene_lists_photos_and_masks() {
    let Some(dir) = common::shared_data("colmap/statue_of_liberty") else {
        return;
    };
    let scene = Scene::load(&SceneSpec {
        dir: Some(dir),
        ..Default::default()
    })
    .unwrap();
    assert_eq!(scene.photos.len(), 40);
    assert!(scene
        .photos
        .iter()
        .all(|p| p.mask.is_some() && p.status() == PhotoStatus::Ok));
    let m = scene.photos[0].load_mask().unwrap().unwrap();
    assert_eq!(m.dimensions(), (800, 1200));
    scene.check_photos().unwrap();
}
