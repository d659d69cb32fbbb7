//! Writing a report page: `report.html` (self-contained) and the renders it embeds, also as
//! `renders/*.png` beside it for other uses. Each file is written atomically.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::io::write_atomic;
use crate::report_html::Page;

/// File name of the page.
pub const REPORT_FILE: &str = "report.html";

/// Writes `dir/report.html` and `dir/renders/NAME` for each `(NAME, PNG bytes)` of `renders`,
/// creating the folders; returns the page's path.
///
/// # Errors
/// [`Error::Invalid`] for a render name that is not a plain `*.png` file name or a page that does
/// not build ([`Page::to_html`]); [`Error::Io`] naming the file when writing fails.
pub fn write_report(dir: &Path, page: &Page, renders: &[(String, Vec<u8>)]) -> Result<PathBuf> {
    for (name, _) in renders {
        let plain = !name.is_empty()
            && name.ends_with(".png")
            && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
            && !name.starts_with('.');
        if !plain {
            return Err(Error::invalid("render name", format!("`{name}` is not a plain *.png file name")));
        }
    }
    let html = page.to_html()?;
    let renders_dir = dir.join("renders");
    std::fs::create_dir_all(&renders_dir).map_err(|e| Error::io(&renders_dir, e))?;
    for (name, png) in renders {
        write_atomic(&renders_dir.join(name), png)?;
    }
    let path = dir.join(REPORT_FILE);
    write_atomic(&path, html.as_bytes())?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_page_and_renders_and_refuses_odd_names() {
        let dir = tempfile::tempdir().expect("tempdir");
        let page = Page { title: "t".into(), sections: Vec::new() };
        let path = write_report(dir.path(), &page, &[("a.png".into(), b"png".to_vec())]).expect("write");
        assert_eq!(path, dir.path().join("report.html"));
        assert!(std::fs::read_to_string(&path).expect("html").contains("<title>t</title>"));
        assert_eq!(std::fs::read(dir.path().join("renders/a.png")).expect("png"), b"png");
        for bad in ["../a.png", "a.txt", ".png", "a/b.png"] {
            let out = dir.path().join("bad");
            assert!(write_report(&out, &page, &[(bad.into(), Vec::new())]).is_err(), "{bad}");
            assert!(!out.exists(), "{bad}: nothing written");
        }
    }
}
