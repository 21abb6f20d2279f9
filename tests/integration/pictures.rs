//! `coid render`: instances drawn as PNG and SVG.

use crate::util::*;

#[test]
fn render_draws_real_instances_as_png_and_svg() {
    let (fx, cfg) = Fixture::with_config(80.0, "");
    let render = |out: &str, instances: &str| {
        let cmd = fx.cmd("render").config(&cfg).out(out);
        cmd.args(["--instances", instances]).output()
    };
    assert_ok(&render("pics", "0,1"));
    for name in ["instance-0000", "instance-0001"] {
        let png = fx.path("pics").join(format!("{name}.png"));
        let img = image::open(&png).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (1000, 1000));
        let colours: std::collections::HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
        assert!(colours.len() > 20, "{name}: only {} colours", colours.len());
        assert!(fx.path("pics").join(format!("{name}.svg")).is_file());
    }
    let bad = render("none", "100000");
    assert_refused_unwritten(&bad, "no instance", &fx.path("none"));
}
