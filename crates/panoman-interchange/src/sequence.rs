//! Mesh sequences on disk: a folder of per-frame meshes (what `panoman track` writes: one
//! `<frame>.obj` per keypoints file, next to `<frame>.params.json` and `summary.json`).

use std::path::{Path, PathBuf};

use panoman_mesh::io::read_mesh;

use crate::error::{InterchangeError, Result};

/// Frames sharing one face list, read from mesh files.
#[derive(Clone, Debug, PartialEq)]
pub struct Sequence {
    /// The file of each frame, in frame order.
    pub files: Vec<PathBuf>,
    /// The shared triangles.
    pub faces: Vec<[u32; 3]>,
    /// Vertex positions per frame (metres).
    pub frames: Vec<Vec<[f64; 3]>>,
}

impl Sequence {
    /// A one-frame sequence from a mesh file (`.obj` / `.ply`).
    ///
    /// # Errors
    /// Errors of [`read_mesh`], naming the file.
    pub fn from_mesh(path: &Path) -> Result<Sequence> {
        let mesh = read_mesh(path)?;
        Ok(Sequence {
            files: vec![path.to_path_buf()],
            faces: mesh.faces,
            frames: vec![mesh.positions],
        })
    }

    /// The frames of a folder: its `.obj` and `.ply` files (case-insensitive extension; names
    /// starting with `.` are skipped) in byte order of their names.
    ///
    /// # Errors
    /// The folder cannot be listed or holds no mesh files; a mesh cannot be read; a frame's
    /// vertex count or face list differs from the first frame's (naming both files).
    pub fn from_dir(dir: &Path) -> Result<Sequence> {
        let entries = std::fs::read_dir(dir).map_err(|e| InterchangeError::io(dir, e))?;
        let mut files = Vec::new();
        for entry in entries {
            let path = entry.map_err(|e| InterchangeError::io(dir, e))?.path();
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            let ext = path
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase());
            if name.is_some_and(|n| !n.starts_with('.'))
                && matches!(ext.as_deref(), Some("obj" | "ply"))
                && path.is_file()
            {
                files.push(path);
            }
        }
        files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
        let Some(first) = files.first().cloned() else {
            return Err(InterchangeError::format(
                dir,
                "no .obj or .ply frames in this folder",
            ));
        };
        let mut seq = Sequence::from_mesh(&first)?;
        for path in &files[1..] {
            let mesh = read_mesh(path)?;
            if mesh.positions.len() != seq.frames[0].len() {
                return Err(InterchangeError::format(
                    path,
                    format!(
                        "{} vertices, but the first frame {} has {}: all frames of a sequence \
                         must share one mesh topology",
                        mesh.positions.len(),
                        first.display(),
                        seq.frames[0].len()
                    ),
                ));
            }
            if mesh.faces != seq.faces {
                return Err(InterchangeError::format(
                    path,
                    format!(
                        "its face list differs from the first frame {}: all frames of a \
                         sequence must share one mesh topology",
                        first.display()
                    ),
                ));
            }
            seq.frames.push(mesh.positions);
            seq.files.push(path.clone());
        }
        Ok(seq)
    }

    /// [`Sequence::from_dir`] for a folder, else [`Sequence::from_mesh`].
    ///
    /// # Errors
    /// See those functions.
    pub fn read(path: &Path) -> Result<Sequence> {
        if path.is_dir() {
            Sequence::from_dir(path)
        } else {
            Sequence::from_mesh(path)
        }
    }
}
