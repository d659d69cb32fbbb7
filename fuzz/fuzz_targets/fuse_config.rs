//! The fuse config as `awl fuse --config` reads it: JSON (`null` turns a stage off) merged over the
//! defaults, or TOML (parsed as the config, then merged key by key), then checked. The library's
//! errors name the key (the CLI adds the file).
#![no_main]
use libfuzzer_sys::fuzz_target;

use awl::pipeline::FuseConfig;

fuzz_target!(|data: &[u8]| {
    if let Ok(json) = serde_json::from_slice::<serde_json::Value>(data) {
        if let Ok(config) = FuseConfig::with_overrides(&json) {
            let _ = config.check();
        }
    }
    let Ok(text) = std::str::from_utf8(data) else { return };
    if toml::from_str::<FuseConfig>(text).is_err() {
        return;
    }
    let Ok(document) = toml::from_str::<toml::Value>(text) else { return };
    let Ok(document) = serde_json::to_value(document) else { return };
    if let Ok(config) = FuseConfig::with_overrides(&document) {
        let _ = config.check();
    }
});
