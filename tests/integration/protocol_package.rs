//! The ethics board's protocol package through the real server: the page is the study's
//! hashed parameters — the canonical JSON it prints hashes (SHA-256, computed here) to the
//! hash on its running head and foot, which is the hash the first enrolment locks —, a changed
//! parameter changes the document and the hash, user text is escaped, and the page keeps the
//! strict CSP (no inline script or style; its stylesheet repeats head and foot on every
//! printed page).

use bdft_tests::server::{Api, Server, with_store};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};

/// HTML text back to the text it escapes.
fn unescape(s: &str) -> String {
    s.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&amp;", "&")
}

/// The canonical JSON the page prints, and its SHA-256 (hex).
fn printed_protocol(html: &str) -> (Value, String) {
    let start = html
        .find("<pre class=\"canonical\">")
        .expect("the appendix")
        + 23;
    let text = unescape(&html[start..start + html[start..].find("</pre>").unwrap()]);
    let hash: String = Sha256::digest(text.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    (serde_json::from_str(&text).unwrap(), hash)
}

/// The page's own markup has no inline script, style or event handler, and every script is
/// a file of this server.
fn assert_no_inline_code(html: &str) {
    for (i, _) in html.match_indices("<script") {
        let tag = &html[i..i + html[i..].find('>').unwrap()];
        assert!(tag.contains(" src=\"/"), "an inline script: {tag}");
        assert!(html[i..].starts_with(&format!("{tag}></script>")));
    }
    assert!(!html.contains("<style") && !html.contains(" style="));
    let lower = html.to_ascii_lowercase();
    for (i, _) in lower.match_indices(" on") {
        let name: String = lower[i + 1..]
            .chars()
            .take_while(char::is_ascii_alphabetic)
            .collect();
        assert!(
            !lower[i + 1 + name.len()..].starts_with('='),
            "an event handler attribute {name}"
        );
    }
}

#[test]
fn the_package_is_the_hashed_protocol_with_its_hash_on_every_page() {
    let server = Server::start("protocol-package");
    let api = server.experimenter();
    let (_, mut params) = api.get("/api/defaults");
    params["consent"]["text"] =
        json!("You agree <script>alert('consent')</script> & take {tests} tests.");
    let made = api.ok(
        "/api/studies",
        json!({ "name": "<script>alert(1)</script> & co", "params": params, "seed": 7 }),
    );
    let study = made["id"].as_i64().unwrap();
    let path = format!("/api/studies/{study}/protocol.html");

    let (status, headers, html) = api.get_page(&path);
    assert_eq!(status, 200, "{html}");
    assert!(headers["content-type"].starts_with("text/html"));
    let (_, dashboard_headers, _) = api.get_page("/");
    let csp = &headers["content-security-policy"];
    assert_eq!(csp, &dashboard_headers["content-security-policy"]);
    assert!(
        csp.contains("script-src 'self'")
            && csp.contains("style-src 'self'")
            && !csp.contains("unsafe"),
        "{csp}"
    );
    assert_eq!(headers["x-content-type-options"], "nosniff");
    assert_no_inline_code(&html);
    assert!(!html.contains("<script>alert"), "user text unescaped");
    // The key that signs the audit log's checkpoints, as the server signed its first one.
    let key: String = with_store(&server, async |pool| {
        sqlx::query_scalar("SELECT public_key FROM audit_checkpoints ORDER BY id DESC LIMIT 1")
            .fetch_one(pool)
            .await
            .unwrap()
    });
    assert_eq!(key.len(), 64, "{key}");
    assert!(
        html.contains(&format!(
            "Audit log signing key (Ed25519, public)</td><td>{key}"
        )),
        "the package names the audit key {key}"
    );
    assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt; &amp; co"));
    assert!(
        html.contains(
            "You agree &lt;script&gt;alert('consent')&lt;/script&gt; &amp; take 10 tests."
        )
    );

    // Every item the ethics board approves has its section.
    for section in [
        "consent",
        "instructions",
        "schedule",
        "randomization",
        "targets",
        "compensators",
        "surveys",
        "stopping",
        "data",
        "appendix",
    ] {
        assert!(
            html.contains(&format!("<h2 id=\"{section}\">")),
            "{section}"
        );
    }

    // One source: the parameters printed are the study's, and they hash to the hash shown
    // on the running head and foot.
    let (printed, hash) = printed_protocol(&html);
    let (_, st) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(printed, st["params"]);
    assert_eq!(
        html.matches(&format!("<code class=\"hash\">{hash}</code>"))
            .count(),
        2,
        "the head and the foot"
    );
    assert!(html.contains("not locked yet"));
    assert!(html.contains("above 6000 mm/s²"), "the interlock limit");
    let (status, css_headers, css) = api.get_page("/protocol.css");
    assert_eq!(status, 200);
    assert!(css_headers["content-type"].starts_with("text/css"));
    for rule in ["table-header-group", "table-footer-group", "@media print"] {
        assert!(css.contains(rule), "{rule}");
    }
    assert_eq!(api.get_page("/protocol.js").0, 200);

    // A changed parameter changes the document and the hash.
    let mut changed = st["params"].clone();
    changed["max_cab_rms_mm_s2"] = json!(4321.5);
    let (status, body) = api.call(
        "PUT",
        &format!("/api/studies/{study}"),
        Some(json!({ "name": st["name"], "params": changed, "version": st["version"] })),
    );
    assert_eq!(status, 200, "{body}");
    let (_, _, html2) = api.get_page(&path);
    let (printed2, hash2) = printed_protocol(&html2);
    assert_ne!(hash2, hash);
    assert_eq!(printed2, changed);
    assert!(html2.contains("above 4321.5 mm/s²") && !html2.contains(&hash));
    assert!(html2.contains(&format!("<code class=\"hash\">{hash2}</code>")));

    // The first enrolment locks exactly that hash, and the page says it is locked.
    api.ok(&format!("/api/studies/{study}/subjects"), json!({}));
    let (_, locked) = api.get(&format!("/api/studies/{study}"));
    assert_eq!(locked["protocol_hash"], hash2.as_str());
    let (_, _, html3) = api.get_page(&path);
    assert_eq!(
        html3
            .matches(&format!("<code class=\"hash\">{hash2}</code>"))
            .count(),
        2
    );
    assert!(html3.contains("· locked ") && !html3.contains("not locked yet"));

    // Anyone logged in may read it (an analyst too); nobody else; an unknown study is a 404.
    let (_, analyst) = server.account(&api, "ana", "analyst");
    assert_eq!(analyst.get_page(&path).0, 200);
    assert_eq!(Api::anonymous(&server.base).get_page(&path).0, 401);
    assert_eq!(api.get_page("/api/studies/999999/protocol.html").0, 404);
}
