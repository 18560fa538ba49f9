//! The library's error type. Every variant names the file and, where it can, the line, byte
//! offset or element at fault, so that a user can go straight to the broken record.

use std::fmt;
use std::path::{Path, PathBuf};

/// Where in a file a problem was found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Location {
    /// Nothing more precise than the file.
    File,
    /// 1-based line of a text file.
    Line(usize),
    /// Byte offset into a binary file.
    Byte(u64),
    /// A named element, such as `vertex 12` or `image 7 (IMG_0001.JPG)`.
    Element(String),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::File => Ok(()),
            Location::Line(n) => write!(f, ":{n}"),
            Location::Byte(b) => write!(f, " (byte {b})"),
            Location::Element(e) => write!(f, " ({e})"),
        }
    }
}

/// The part of a mesh an error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshElement {
    /// The mesh as a whole (it lacks something the request needs).
    Whole,
    /// A face, by its 0-based index in the loaded (welded) mesh.
    Face(usize),
    /// A vertex, by its 0-based index in the loaded (welded) mesh.
    Vertex(usize),
}

impl fmt::Display for MeshElement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MeshElement::Whole => Ok(()),
            MeshElement::Face(i) => write!(f, " face {i}"),
            MeshElement::Vertex(i) => write!(f, " vertex {i}"),
        }
    }
}

/// All errors scantex's library returns.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The operating system refused to read or write a file.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A file was read but its content is wrong.
    #[error("{}{location}: {msg}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// Where in the file.
        location: Location,
        /// What is wrong, in words a user can act on.
        msg: String,
    },
    /// A directory does not hold what it was given for (no COLMAP model, several meshes).
    #[error("{}: {msg}", path.display())]
    Directory {
        /// The directory.
        path: PathBuf,
        /// What is wrong, and what to do.
        msg: String,
    },
    /// The mesh, or one of its elements, makes the request impossible (no texture coordinates
    /// to keep, a face outside the texture page).
    #[error("mesh{element}: {msg}")]
    Mesh {
        /// The element at fault.
        element: MeshElement,
        /// What is wrong with it.
        msg: String,
    },
    /// A registered photograph cannot be used (its file is not a readable image).
    #[error("image {image_id}: {msg}")]
    Photo {
        /// The image's COLMAP id.
        image_id: u32,
        /// What is wrong, naming the file.
        msg: String,
    },
    /// The inputs are individually valid but do not fit together as a whole (a scene without
    /// photographs, a mesh no photograph sees, more photographs than an atlas can record).
    #[error("{0}")]
    Invalid(String),
    /// An option's value is out of range. `option` is the field of the options struct, which
    /// the command line spells with hyphens (`max_hole` is `--max-hole`).
    #[error("option --{}: {msg}", .option.replace('_', "-"))]
    BadOption {
        /// The option's field name.
        option: &'static str,
        /// What is wrong with its value.
        msg: String,
    },
    /// A check of scantex's own invariants failed: a bug in scantex, not a fault of the input.
    #[error("internal error (a bug in scantex; please report it): {0}")]
    Internal(String),
}

/// Shorthand used throughout the crate.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }

    /// A content error in `path` at `location`.
    pub fn parse(path: impl AsRef<Path>, location: Location, msg: impl Into<String>) -> Self {
        Error::Parse {
            path: path.as_ref().to_path_buf(),
            location,
            msg: msg.into(),
        }
    }

    /// An out-of-range value of the option `option` (a field name of an options struct).
    pub fn option(option: &'static str, msg: impl Into<String>) -> Self {
        Error::BadOption {
            option,
            msg: msg.into(),
        }
    }

    /// A fault of the mesh's `element`.
    pub fn mesh(element: MeshElement, msg: impl Into<String>) -> Self {
        Error::Mesh {
            element,
            msg: msg.into(),
        }
    }

    /// A content error at a 1-based line of a text file.
    pub fn at_line(path: impl AsRef<Path>, line: usize, msg: impl Into<String>) -> Self {
        Self::parse(path, Location::Line(line), msg)
    }

    /// A content error about a named element of a file.
    pub fn at_element(
        path: impl AsRef<Path>,
        element: impl Into<String>,
        msg: impl Into<String>,
    ) -> Self {
        Self::parse(path, Location::Element(element.into()), msg)
    }
}
