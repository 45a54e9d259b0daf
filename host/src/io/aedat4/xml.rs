//! The IOHeader's `infoNode` XML: stream declarations (read) and escaping (write).

/// One stream declared in the header XML.
#[derive(Debug, Default)]
pub(super) struct StreamDecl {
    pub(super) id: i32,
    pub(super) type_id: String,
    pub(super) width: Option<u16>,
    pub(super) height: Option<u16>,
    pub(super) source: Option<String>,
}

/// A tag of an XML document; `attrs` is the raw attribute text.
pub(super) enum Tag<'a> {
    Open {
        name: &'a str,
        attrs: &'a str,
        empty: bool,
    },
    Close(&'a str),
}

/// Splits XML into (text before, tag) pairs; skips comments, declarations and instructions.
pub(super) struct Tags<'a> {
    pub(super) s: &'a str,
    pub(super) pos: usize,
}

impl<'a> Tags<'a> {
    pub(super) fn next_tag(&mut self) -> Result<Option<(&'a str, Tag<'a>)>, String> {
        loop {
            let rest = &self.s[self.pos..];
            let Some(lt) = rest.find('<') else {
                return Ok(None);
            };
            let (text, tag, at) = (&rest[..lt], &rest[lt..], self.pos + lt);
            let skip_to = |end: &str| {
                tag.find(end)
                    .map(|i| i + end.len())
                    .ok_or_else(|| format!("unterminated markup at {at}"))
            };
            if tag.starts_with("<!--") {
                self.pos += lt + skip_to("-->")?;
            } else if tag.starts_with("<?") {
                self.pos += lt + skip_to("?>")?;
            } else if tag.starts_with("<!") {
                self.pos += lt + skip_to(">")?;
            } else {
                let end = tag_end(tag).ok_or_else(|| format!("unterminated tag at {at}"))?;
                self.pos += lt + end + 1;
                return Ok(Some((text, parse_tag(&tag[1..end]))));
            }
        }
    }
}

/// Index of the `>` that closes the tag starting `tag`, skipping quoted attribute values.
pub(super) fn tag_end(tag: &str) -> Option<usize> {
    let mut quote = None;
    for (i, c) in tag.char_indices() {
        match (quote, c) {
            (None, '"' | '\'') => quote = Some(c),
            (Some(q), _) if c == q => quote = None,
            (None, '>') => return Some(i),
            _ => {}
        }
    }
    None
}

pub(super) fn parse_tag(inner: &str) -> Tag<'_> {
    if let Some(name) = inner.strip_prefix('/') {
        return Tag::Close(name.trim());
    }
    let (inner, empty) = match inner.strip_suffix('/') {
        Some(s) => (s, true),
        None => (inner, false),
    };
    let split = inner.find(char::is_whitespace).unwrap_or(inner.len());
    Tag::Open {
        name: &inner[..split],
        attrs: &inner[split..],
        empty,
    }
}

/// The unescaped value of attribute `key` in raw attribute text.
pub(super) fn xml_attr(attrs: &str, key: &str) -> Option<String> {
    let mut rest = attrs;
    loop {
        rest = rest.trim_start();
        let eq = rest.find('=')?;
        let name = rest[..eq].trim();
        let after = rest[eq + 1..].trim_start();
        let quote = after.chars().next().filter(|&c| c == '"' || c == '\'')?;
        let body = &after[1..];
        let close = body.find(quote)?;
        if name == key {
            return Some(unescape(&body[..close]));
        }
        rest = &body[close + 1..];
    }
}

/// Replaces the predefined and numeric XML entities; leaves unknown ones as they are.
pub(super) fn unescape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(amp) = rest.find('&') {
        out.push_str(&rest[..amp]);
        rest = &rest[amp..];
        let decoded = rest.find(';').and_then(|semi| {
            let c = match &rest[1..semi] {
                "lt" => Some('<'),
                "gt" => Some('>'),
                "amp" => Some('&'),
                "quot" => Some('"'),
                "apos" => Some('\''),
                e => e
                    .strip_prefix("#x")
                    .map(|h| u32::from_str_radix(h, 16))
                    .or_else(|| e.strip_prefix('#').map(str::parse::<u32>))
                    .and_then(Result::ok)
                    .and_then(char::from_u32),
            };
            c.map(|c| (c, semi + 1))
        });
        match decoded {
            Some((c, len)) => {
                out.push(c);
                rest = &rest[len..];
            }
            None => {
                out.push('&');
                rest = &rest[1..];
            }
        }
    }
    out.push_str(rest);
    out
}

pub(super) fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&apos;")
}

/// The streams declared under `<node name="outInfo">`, in document order.
pub(super) fn parse_streams(xml: &str) -> Result<Vec<StreamDecl>, String> {
    let mut tags = Tags { s: xml, pos: 0 };
    // Open elements: (tag name, `name` attribute).
    let mut stack: Vec<(&str, Option<String>)> = Vec::new();
    let mut streams: Vec<StreamDecl> = Vec::new();
    let mut attr_key: Option<String> = None;
    while let Some((text, tag)) = tags.next_tag()? {
        match tag {
            Tag::Open { name, attrs, empty } => {
                let out_info = stack
                    .iter()
                    .position(|(t, n)| *t == "node" && n.as_deref() == Some("outInfo"));
                if name == "node" && out_info.is_some_and(|i| stack.len() == i + 1) {
                    streams.push(stream_decl(attrs)?);
                }
                if name == "attr" {
                    attr_key = xml_attr(attrs, "key");
                    if empty {
                        attr_value(&stack, &mut streams, attr_key.take(), "");
                    }
                }
                if !empty {
                    stack.push((name, xml_attr(attrs, "name")));
                }
            }
            Tag::Close(name) => {
                if stack.pop().map(|(t, _)| t) != Some(name) {
                    return Err(format!("unexpected </{name}>"));
                }
                if name == "attr" {
                    attr_value(&stack, &mut streams, attr_key.take(), text);
                }
            }
        }
    }
    match stack.last() {
        Some((t, _)) => Err(format!("<{t}> is never closed")),
        None => Ok(streams),
    }
}

pub(super) fn stream_decl(attrs: &str) -> Result<StreamDecl, String> {
    let name = xml_attr(attrs, "name").unwrap_or_default();
    let id = name
        .trim()
        .parse()
        .map_err(|_| format!("stream node name {name:?} is not an integer"))?;
    Ok(StreamDecl {
        id,
        ..StreamDecl::default()
    })
}

/// Records `<attr key="key">text</attr>` when it belongs to a stream or its `info` node.
pub(super) fn attr_value(
    stack: &[(&str, Option<String>)],
    streams: &mut [StreamDecl],
    key: Option<String>,
    text: &str,
) {
    let (Some(key), Some(stream)) = (key, streams.last_mut()) else {
        return;
    };
    let Some(out_info) = stack
        .iter()
        .position(|(t, n)| *t == "node" && n.as_deref() == Some("outInfo"))
    else {
        return;
    };
    let value = unescape(text.trim());
    let inner = &stack[out_info + 1..];
    match inner {
        [("node", _)] if key == "typeIdentifier" => stream.type_id = value,
        [(_, _), ("node", Some(info))] if info == "info" => match key.as_str() {
            "sizeX" => stream.width = value.parse().ok(),
            "sizeY" => stream.height = value.parse().ok(),
            "source" => stream.source = Some(value),
            _ => {}
        },
        _ => {}
    }
}

// ---------------------------------------------------------------------------------------------
// Reader.
