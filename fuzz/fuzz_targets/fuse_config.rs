//! The fuse config as `awl fuse --config` reads it: JSON or TOML merged over the defaults
//! (`false`, or JSON's `null`, switches a stage off), then checked; and the resolved config
//! printed as `--print-config` prints it. The library's errors name the key (the CLI adds the file).
#![no_main]
use libfuzzer_sys::fuzz_target;

use awl::pipeline::FuseConfig;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    for config in [FuseConfig::from_json_on(FuseConfig::default(), text), FuseConfig::from_toml_on(FuseConfig::default(), text)]
        .into_iter()
        .flatten()
    {
        if config.check().is_ok() {
            let _ = config.documented_toml();
        }
    }
});
