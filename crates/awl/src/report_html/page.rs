//! A generic, self-contained report page: sections of text, key/value tables, tables, PNG images
//! (base64 data URIs), inline SVG and interactive point clouds. The HTML opens offline (no CDN);
//! JavaScript errors are written into `<pre id="js-errors">` so a headless browser's DOM dump shows
//! them.

use std::collections::HashSet;
use std::fmt::Write;

use super::base64;
use super::viewer::{VIEWER_JS, ViewerCloud};
use crate::error::{Error, Result};
use crate::render::plot::xml_escape;

/// A report page.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Page {
    /// Title (the `<title>` and the heading).
    pub title: String,
    /// Sections in order.
    pub sections: Vec<Section>,
}

/// A titled section.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Section {
    /// Heading.
    pub heading: String,
    /// Content in order.
    pub blocks: Vec<Block>,
}

/// One row of a key/value table; `id` (letters, digits, `-`, `_`; unique in the page) goes on the
/// value cell so tests and scripts can find it.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyValue {
    /// The key.
    pub key: String,
    /// The value, as shown.
    pub value: String,
    /// Element id of the value cell.
    pub id: Option<String>,
}

impl KeyValue {
    /// A row without an id.
    pub fn new(key: &str, value: impl Into<String>) -> Self {
        Self { key: key.into(), value: value.into(), id: None }
    }
    /// A row whose value cell has `id`.
    pub fn with_id(key: &str, value: impl Into<String>, id: &str) -> Self {
        Self { key: key.into(), value: value.into(), id: Some(id.into()) }
    }
}

/// A table with a header row; each row may carry a CSS class (`accepted`, `rejected`, `skipped`
/// are styled).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Table {
    /// Column titles.
    pub header: Vec<String>,
    /// Rows: cells and an optional class.
    pub rows: Vec<(Vec<String>, Option<String>)>,
    /// Element id of the table.
    pub id: Option<String>,
}

/// A PNG picture.
#[derive(Debug, Clone, PartialEq)]
pub struct Picture {
    /// Caption (and alt text).
    pub caption: String,
    /// The PNG file's bytes.
    pub png: Vec<u8>,
}

/// Content of a section.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    /// A paragraph of plain text.
    Text(String),
    /// A bulleted list of plain-text items.
    List(Vec<String>),
    /// Warnings that put the page's figures in doubt: a red box (`id="warnings"`), one item each.
    Alert(Vec<String>),
    /// A two-column key/value table.
    KeyValues(Vec<KeyValue>),
    /// A table.
    Table(Table),
    /// Pictures side by side (wrapping).
    Pictures(Vec<Picture>),
    /// Inline SVG markup (from [`crate::render::plot`]; inserted as is).
    Svg(String),
    /// An interactive 3D view.
    Cloud(ViewerCloud),
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1200px}\
h1{font-size:22px}h2{font-size:17px;border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:28px}\
table{border-collapse:collapse;margin:8px 0;font-size:13px}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}\
th{background:#f2f2f2}tr.accepted td{background:#eef8ee}tr.rejected td{background:#fbeaea}tr.skipped td{color:#999}\
figure{display:inline-block;margin:6px}figure img{width:560px;max-width:100%;border:1px solid #ddd}figcaption{font-size:12px;color:#555}\
.viewer canvas{width:960px;max-width:100%;border:1px solid #888;cursor:grab}.hint{font-size:12px;color:#555}\
.svg{display:inline-block;margin:6px}\
.alert{background:#fdecea;border:3px solid #b00;color:#600;padding:4px 12px;font-size:15px;font-weight:bold}#js-errors:empty{display:none}#js-errors{color:#b00;border:1px solid #b00;padding:6px}";

/// Collects uncaught errors, rejected promises and console.error calls into #js-errors.
const ERROR_CAPTURE: &str = "(function(){var q=[];function put(m){var el=document.getElementById('js-errors');\
if(el){el.textContent+=m+'\\n';}else{q.push(m);}}\
window.addEventListener('error',function(e){put('error: '+e.message+' at '+(e.filename||'')+':'+(e.lineno||0));});\
window.addEventListener('unhandledrejection',function(e){put('unhandled rejection: '+e.reason);});\
var ce=console.error;console.error=function(){put('console.error: '+Array.prototype.join.call(arguments,' '));\
return ce.apply(console,arguments);};document.addEventListener('DOMContentLoaded',function(){q.forEach(put);q=[];});})();";

fn check_id(id: &str, seen: &mut HashSet<String>) -> Result<()> {
    let ok = !id.is_empty() && id.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    if !ok {
        return Err(Error::invalid("page element id", format!("`{id}`: use letters, digits, - and _")));
    }
    if !seen.insert(id.to_string()) {
        return Err(Error::invalid("page element id", format!("`{id}` is used twice")));
    }
    Ok(())
}

impl Page {
    /// The page as one self-contained HTML document.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a malformed or repeated element id, a table row with a wrong cell
    /// count, or an empty cloud.
    pub fn to_html(&self) -> Result<String> {
        let mut ids = HashSet::new();
        for reserved in ["js-errors", "page-title"] {
            ids.insert(reserved.to_string());
        }
        let title = xml_escape(&self.title);
        let mut s = format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{title}</title>\n\
             <script>{ERROR_CAPTURE}</script>\n<style>{STYLE}</style>\n</head>\n<body>\n<h1 id=\"page-title\">{title}</h1>\n\
             <pre id=\"js-errors\"></pre>\n"
        );
        let mut clouds = 0;
        for section in &self.sections {
            let _ = writeln!(s, "<section>\n<h2>{}</h2>", xml_escape(&section.heading));
            for block in &section.blocks {
                block_html(&mut s, block, &mut ids, &mut clouds)?;
            }
            s.push_str("</section>\n");
        }
        if clouds > 0 {
            let _ = writeln!(s, "<script>\n{VIEWER_JS}</script>");
        }
        s.push_str("</body>\n</html>\n");
        Ok(s)
    }
}

fn block_html(s: &mut String, block: &Block, ids: &mut HashSet<String>, clouds: &mut usize) -> Result<()> {
    match block {
        Block::Text(text) => {
            let _ = writeln!(s, "<p>{}</p>", xml_escape(text));
        }
        Block::Alert(items) => {
            s.push_str("<div class=\"alert\" id=\"warnings\" role=\"alert\">\n<ul>\n");
            for item in items {
                let _ = writeln!(s, "<li>{}</li>", xml_escape(item));
            }
            s.push_str("</ul>\n</div>\n");
        }
        Block::List(items) => {
            s.push_str("<ul>\n");
            for item in items {
                let _ = writeln!(s, "<li>{}</li>", xml_escape(item));
            }
            s.push_str("</ul>\n");
        }
        Block::KeyValues(rows) => {
            s.push_str("<table class=\"kv\">\n");
            for row in rows {
                let id = match &row.id {
                    Some(id) => {
                        check_id(id, ids)?;
                        format!(" id=\"{id}\"")
                    }
                    None => String::new(),
                };
                let _ =
                    writeln!(s, "<tr><th>{}</th><td{id}>{}</td></tr>", xml_escape(&row.key), xml_escape(&row.value));
            }
            s.push_str("</table>\n");
        }
        Block::Table(table) => table_html(s, table, ids)?,
        Block::Pictures(pictures) => {
            for p in pictures {
                let caption = xml_escape(&p.caption);
                let _ = writeln!(
                    s,
                    "<figure><img alt=\"{caption}\" src=\"data:image/png;base64,{}\"><figcaption>{caption}</figcaption></figure>",
                    base64::encode(&p.png)
                );
            }
        }
        Block::Svg(svg) => {
            let _ = writeln!(s, "<div class=\"svg\">{svg}</div>");
        }
        Block::Cloud(cloud) => {
            if cloud.is_empty() {
                return Err(Error::invalid("page cloud", "has no points"));
            }
            let k = *clouds;
            for id in [format!("viewer-{k}"), format!("viewer-status-{k}"), format!("cloud-{k}-pos")] {
                check_id(&id, ids)?;
            }
            s.push_str(&cloud.html(k));
            *clouds += 1;
        }
    }
    Ok(())
}

fn table_html(s: &mut String, table: &Table, ids: &mut HashSet<String>) -> Result<()> {
    let id = match &table.id {
        Some(id) => {
            check_id(id, ids)?;
            format!(" id=\"{id}\"")
        }
        None => String::new(),
    };
    let _ = write!(s, "<table{id}>\n<tr>");
    for h in &table.header {
        let _ = write!(s, "<th>{}</th>", xml_escape(h));
    }
    s.push_str("</tr>\n");
    for (k, (cells, class)) in table.rows.iter().enumerate() {
        if cells.len() != table.header.len() {
            return Err(Error::invalid(
                "page table",
                format!("row {k} has {} cells for {} columns", cells.len(), table.header.len()),
            ));
        }
        match class {
            Some(c) => {
                let _ = write!(s, "<tr class=\"{}\">", xml_escape(c));
            }
            None => s.push_str("<tr>"),
        }
        for c in cells {
            let _ = write!(s, "<td>{}</td>", xml_escape(c));
        }
        s.push_str("</tr>\n");
    }
    s.push_str("</table>\n");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn page_escapes_text_and_checks_ids() {
        let page = Page {
            title: "a <b> & c".into(),
            sections: vec![Section {
                heading: "Summary".into(),
                blocks: vec![
                    Block::KeyValues(vec![KeyValue::with_id("points", "12", "points"), KeyValue::new("x", "<y>")]),
                    Block::Table(Table {
                        header: vec!["a".into(), "b".into()],
                        rows: vec![(vec!["1".into(), "2".into()], Some("accepted".into()))],
                        id: Some("views".into()),
                    }),
                    Block::Pictures(vec![Picture { caption: "front".into(), png: b"foo".to_vec() }]),
                ],
            }],
        };
        let html = page.to_html().expect("valid");
        assert!(html.contains("<title>a &lt;b&gt; &amp; c</title>"));
        assert!(html.contains("<td id=\"points\">12</td>"));
        assert!(html.contains("<td>&lt;y&gt;</td>"));
        assert!(html.contains("<tr class=\"accepted\"><td>1</td><td>2</td></tr>"));
        assert!(html.contains("src=\"data:image/png;base64,Zm9v\""));
        assert!(!html.contains("awl-viewer\" width"), "no viewer without a cloud");
        assert!(!html.contains("src=\"http") && !html.contains("href=\"http"), "nothing fetched");
        let mut dup = page.clone();
        dup.sections[0].blocks.push(Block::KeyValues(vec![KeyValue::with_id("again", "1", "points")]));
        assert!(dup.to_html().is_err(), "duplicate id");
        let mut bad = page.clone();
        bad.sections[0].blocks.push(Block::KeyValues(vec![KeyValue::with_id("q", "1", "a b")]));
        assert!(bad.to_html().is_err(), "malformed id");
        let mut ragged = page;
        ragged.sections[0].blocks.push(Block::Table(Table {
            header: vec!["a".into()],
            rows: vec![(vec![], None)],
            id: None,
        }));
        assert!(ragged.to_html().is_err(), "row length");
    }
}
