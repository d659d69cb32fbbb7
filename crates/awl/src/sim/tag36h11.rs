//! The tag36h11 family's first ten tags as 10x10 module bitmaps, embedded so the simulator needs no
//! data files at run time.
//!
//! Each bitmap is the canonical AprilTag image (`tag36_11_0000N.png` of apriltag-imgs): a one-module
//! white quiet zone, a one-module black border, then 6x6 data modules. Row 0 is the top of the tag
//! read upright; `#` is black, `.` is white. The black border's outer edge is the tag `size`, so the
//! whole 10-module image is `10 / 8 * size` wide.

/// Modules across the whole bitmap, quiet zone included.
pub const TAG_MODULES: usize = 10;

/// Modules across the black border's outer edge (the tag `size`).
pub const TAG_BORDER_MODULES: usize = 8;

/// Number of embedded tag ids (0 ..= 9).
pub const TAG36H11_EMBEDDED: u32 = 10;

const BITMAPS: [[[u8; TAG_MODULES]; TAG_MODULES]; TAG36H11_EMBEDDED as usize] = [
    // id 0
    [
        *b"..........",
        *b".########.",
        *b".#..#.#.#.",
        *b".##...#.#.",
        *b".##..####.",
        *b".#.#.####.",
        *b".##.#..##.",
        *b".####.###.",
        *b".########.",
        *b"..........",
    ],
    // id 1
    [
        *b"..........",
        *b".########.",
        *b".#..#..##.",
        *b".##.#...#.",
        *b".#....###.",
        *b".##..####.",
        *b".#.#..#.#.",
        *b".###.##.#.",
        *b".########.",
        *b"..........",
    ],
    // id 2
    [
        *b"..........",
        *b".########.",
        *b".#..#...#.",
        *b".##.##.##.",
        *b".#.######.",
        *b".###.##.#.",
        *b".####.###.",
        *b".###...##.",
        *b".########.",
        *b"..........",
    ],
    // id 3
    [
        *b"..........",
        *b".########.",
        *b".#...##.#.",
        *b".####...#.",
        *b".#.##...#.",
        *b".#.#.##.#.",
        *b".#..##.##.",
        *b".##..####.",
        *b".########.",
        *b"..........",
    ],
    // id 4
    [
        *b"..........",
        *b".########.",
        *b".#...#.##.",
        *b".#....###.",
        *b".#.#....#.",
        *b".###.#.##.",
        *b".#.######.",
        *b".#.###.##.",
        *b".########.",
        *b"..........",
    ],
    // id 5
    [
        *b"..........",
        *b".########.",
        *b".#....###.",
        *b".#..###.#.",
        *b".#..#..##.",
        *b".#.#.#..#.",
        *b".###...##.",
        *b".#.#..###.",
        *b".########.",
        *b"..........",
    ],
    // id 6
    [
        *b"..........",
        *b".########.",
        *b".######.#.",
        *b".##.#..##.",
        *b".#.#.##.#.",
        *b".##...#.#.",
        *b".#####.##.",
        *b".####.#.#.",
        *b".########.",
        *b"..........",
    ],
    // id 7
    [
        *b"..........",
        *b".########.",
        *b".####.###.",
        *b".####..##.",
        *b".##.#.###.",
        *b".#.#...##.",
        *b".####...#.",
        *b".##.#.###.",
        *b".########.",
        *b"..........",
    ],
    // id 8
    [
        *b"..........",
        *b".########.",
        *b".###.####.",
        *b".#.#.#..#.",
        *b".####...#.",
        *b".##.....#.",
        *b".#...#.##.",
        *b".#.#..#.#.",
        *b".########.",
        *b"..........",
    ],
    // id 9
    [
        *b"..........",
        *b".########.",
        *b".###.##.#.",
        *b".#.##.#.#.",
        *b".#.#.#..#.",
        *b".##.#####.",
        *b".##.###.#.",
        *b".#..##.##.",
        *b".########.",
        *b"..........",
    ],
];

/// The bitmap of tag36h11 `id` as `black[row][col]` (row 0 at the top when read upright), or `None`
/// for an id that is not embedded.
pub fn tag36h11_bitmap(id: u32) -> Option<[[bool; TAG_MODULES]; TAG_MODULES]> {
    let rows = BITMAPS.get(usize::try_from(id).ok()?)?;
    let mut black = [[false; TAG_MODULES]; TAG_MODULES];
    for (out, row) in black.iter_mut().zip(rows) {
        for (b, &c) in out.iter_mut().zip(row) {
            *b = c == b'#';
        }
    }
    Some(black)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn borders_are_black_and_quiet_zone_white() {
        for id in 0..TAG36H11_EMBEDDED {
            let bits = tag36h11_bitmap(id).expect("embedded");
            for i in 0..TAG_MODULES {
                for (r, c) in [(0, i), (9, i), (i, 0), (i, 9)] {
                    assert!(!bits[r][c], "id {id}: quiet zone ({r},{c}) must be white");
                }
            }
            for i in 1..9 {
                for (r, c) in [(1, i), (8, i), (i, 1), (i, 8)] {
                    assert!(bits[r][c], "id {id}: border ({r},{c}) must be black");
                }
            }
        }
        assert!(tag36h11_bitmap(TAG36H11_EMBEDDED).is_none());
    }
}
