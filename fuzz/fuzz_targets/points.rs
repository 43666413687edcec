//! Point clouds: `panoman::read_points` (PLY or OBJ; the first input byte picks the
//! extension: even `.ply`, odd `.obj`).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, body)) = data.split_first() else {
        return;
    };
    let name = if pick % 2 == 0 {
        "points.ply"
    } else {
        "points.obj"
    };
    let path = panoman_fuzz::scratch_file(name, body);
    if let Err(e) = panoman::read_points(&path) {
        panoman_fuzz::assert_names(&e, &path);
    }
});
