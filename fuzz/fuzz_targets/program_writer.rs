//! The robot-program writers (`urscript_of`, `techman_packets_of`) on any words and numbers: every
//! program made must hold only awl's statements (`awl::robot::statements`).
#![no_main]
use libfuzzer_sys::fuzz_target;

use awl::pierce::{ProgramPlan, ProgramTarget, ScriptSpeeds, ToolPoses};
use nalgebra::{Isometry3, Point3, Vector3};

/// Reads f64s and strings off the input, in turn.
struct Input<'a>(&'a [u8]);

impl Input<'_> {
    fn number(&mut self) -> f64 {
        let (head, rest) = self.0.split_at(self.0.len().min(8));
        self.0 = rest;
        let mut b = [0u8; 8];
        b[..head.len()].copy_from_slice(head);
        f64::from_le_bytes(b)
    }

    fn text(&mut self) -> String {
        let n = usize::from(self.0.first().copied().unwrap_or(0)).min(self.0.len().saturating_sub(1));
        let s = String::from_utf8_lossy(&self.0[1.min(self.0.len())..1 + n]).into_owned();
        self.0 = &self.0[(1 + n).min(self.0.len())..];
        s
    }

    fn pose(&mut self) -> Isometry3<f64> {
        let t = Vector3::new(self.number() % 3.0, self.number() % 3.0, self.number() % 3.0);
        Isometry3::new(t, Vector3::new(self.number() % 4.0, self.number() % 4.0, self.number() % 4.0))
    }
}

fuzz_target!(|data: &[u8]| {
    let mut input = Input(data);
    let source = input.text();
    let tcp = (input.number() > 0.0).then(|| (input.text(), input.pose()));
    let targets = (0..data.len() % 4)
        .map(|_| ProgramTarget {
            spec: input.text(),
            p_base: Point3::new(input.number(), input.number(), input.number()),
            left_out: (input.number() > 0.0).then(|| input.text()),
            approach_q: (input.number() > 0.0).then(|| std::array::from_fn(|_| input.number() % 7.0)),
            poses: ToolPoses { approach: input.pose(), pierce: input.pose(), retract: input.pose() },
        })
        .collect();
    let plan = ProgramPlan { source, tcp, targets };
    let speeds = ScriptSpeeds::default();
    if let Ok(ur) = awl::pierce::urscript_of(&plan, &speeds) {
        awl::robot::statements::check_urscript_statements(&ur).expect("only awl's statements");
    }
    if let Ok(tm) = awl::pierce::techman_packets_of(&plan, &speeds) {
        let packets = awl::robot::techman::split_packets(&tm).expect("packets");
        awl::robot::statements::check_techman_statements(&packets).expect("only awl's statements");
    }
});
