//! plan.json as `awl send` reads it (`read_plan_to_send`).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::file("plan.json", data);
    let _ = awl_fuzz::names_the_file(&path, awl::pierce::verify::read_plan_to_send(&path));
});
