//! `.env.sample` against the flags of the built `bdft-server serve`, as its `--help` states
//! them: every variable the sample sets is one of `serve`'s, shown with its default when it
//! has one; every variable of `serve` is in the sample; and the controller's heartbeat the
//! sample mentions is the one the help states (a server unit test ties that to the
//! controller's own constant).

use bdft_tests::{server_cmd, succeeded};
use std::collections::BTreeMap;

/// Each environment variable of `serve --help` with its default, if it has one.
fn serve_help() -> (BTreeMap<String, Option<String>>, String) {
    // No BDFT_* of the test's environment may show through as a value.
    let out = succeeded(server_cmd(["serve", "--help"]).env_clear());
    let help = String::from_utf8(out.stdout).unwrap();
    // One flag's block starts at its `--flag` line (its description is indented further,
    // and may hold a `--flag` of its own) and runs to the next one.
    let mut blocks: Vec<String> = Vec::new();
    for line in help.lines() {
        let text = line.trim_start();
        if text.starts_with('-') && line.len() - text.len() <= 6 {
            blocks.push(String::new());
        }
        if let Some(block) = blocks.last_mut() {
            block.push_str(line);
            block.push('\n');
        }
    }
    let mut vars = BTreeMap::new();
    for block in &blocks {
        let Some(env) = between(block, "[env: ", ['=', ']']) else {
            continue;
        };
        // Clap puts the default after the variable (a description may say "[default: …]"
        // in its own words, for a default that is not a value).
        let after_env = &block[block.find("[env: ").unwrap_or(0)..];
        let default = between(after_env, "[default: ", [']', ']']);
        vars.insert(env.to_string(), default.map(str::to_string));
    }
    (vars, help)
}

/// The text after `start` up to the first of `ends`.
fn between<'a>(text: &'a str, start: &str, ends: [char; 2]) -> Option<&'a str> {
    let rest = &text[text.find(start)? + start.len()..];
    Some(&rest[..rest.find(ends)?])
}

/// The millisecond count after `phrase` in `text`, if it is there.
fn ms_after(text: &str, phrase: &str) -> Option<u64> {
    let rest = &text[text.find(phrase)? + phrase.len()..];
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    rest[digits.len()..]
        .starts_with(" ms")
        .then(|| digits.parse().ok())?
}

#[test]
fn the_env_sample_names_serves_variables_with_their_defaults() {
    let sample = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../.env.sample"))
        .expect(".env.sample at the workspace's root");
    let (flags, help) = serve_help();
    assert!(flags.len() > 20, "{flags:?}\n{help}");

    // `NAME=value` lines, set or commented out (the sample's suggestions).
    let set: Vec<(&str, &str)> = sample
        .lines()
        .filter_map(|l| l.trim_start_matches('#').trim().split_once('='))
        .filter(|(name, _)| {
            name.starts_with("BDFT_") && name.chars().all(|c| c.is_ascii_uppercase() || c == '_')
        })
        .collect();
    let mut wrong = Vec::new();
    for (name, value) in &set {
        match flags.get(*name) {
            None => wrong.push(format!("{name}: not a variable of `serve`")),
            Some(Some(default)) if default != value => wrong.push(format!(
                "{name}={value}: `serve --help` says the default is {default}"
            )),
            Some(_) => {}
        }
    }
    for name in flags.keys() {
        if !set.iter().any(|(n, _)| n == name) {
            wrong.push(format!(
                "{name}: a variable of `serve` the sample does not show"
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));

    // The prose too: the heartbeat the sample states is the help's.
    let prose: String = sample
        .lines()
        .map(|l| l.trim_start_matches('#').trim())
        .collect::<Vec<_>>()
        .join(" ");
    let phrase = "heartbeats every ";
    let stated = ms_after(&help, phrase).expect("`serve --help` states the heartbeat");
    assert_eq!(ms_after(&prose, phrase), Some(stated), "{prose}");
}
