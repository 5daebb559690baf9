use plumenet::layout::Layout;
use plumenet::physics::{wind::WindField, transport::Transport, scheme::Scheme, analytic};
use std::time::Instant;
fn main() {
    if std::env::var("SEQ").is_ok() { faer::set_global_parallelism(faer::Par::Seq); }
    let l = Layout::load(std::path::Path::new("data/layouts/wind-tunnel.json")).unwrap();
    let t = Instant::now();
    let w = WindField::solve(&l).unwrap();
    println!("wind {:?} steps {} res {}", t.elapsed(), w.steps, w.residual);
    let f = w.section_fluxes();
    let (mn, mx) = f.iter().fold((f64::MAX, f64::MIN), |(a,b),&x| (a.min(x), b.max(x)));
    println!("flux min {mn} max {mx}");
    let umax = w.u.iter().fold(0.0f64, |m,&x| m.max(x.abs()));
    println!("umax {umax}");
    let t = Instant::now();
    let tr = Transport::new(&l, &w).unwrap();
    println!("factor {:?}", t.elapsed());
    let c = l.candidates(0.25).unwrap();
    println!("cands {}", c.len());
    let t = Instant::now();
    let b = tr.bank(&c).unwrap();
    println!("bank {:?} {:?}", t.elapsed(), b.dim());
    let t = Instant::now();
    let one = tr.solve(3.0, 2.0).unwrap();
    println!("one {:?} outlet {}", t.elapsed(), tr.outlet_flux(&one));
    // empty arena analytic
    let e = Layout::from_json(r#"{"width_m":18,"height_m":4,"cell_m":0.125,"wind":{"speed_mps":0.75}}"#).unwrap();
    let we = WindField::solve(&e).unwrap();
    println!("empty steps {}", we.steps);
    for s in [Scheme::Central, Scheme::Upwind, Scheme::Exponential] {
        let tr = Transport::with_scheme(&e, &we, s).unwrap();
        for (xs, ys) in [(3.0, 2.0), (3.1, 1.3), (2.0, 0.6)] {
        let f = tr.solve(xs, ys).unwrap();
        let (mut num, mut den) = (0.0, 0.0);
        for ((j,i), &v) in f.indexed_iter() {
            let (x,y) = e.cell_centre(j,i);
            if (x-xs).hypot(y-ys) < 0.5 || x > 17.0 { continue; }
            let a = analytic::point_source_between_walls((x,y),(xs,ys),0.75,0.05,4.0,1.0);
            num += (v-a)*(v-a); den += a*a;
        }
        println!("{s:?} src ({xs},{ys}) relL2 {:.4} outlet {:.5}", (num/den).sqrt(), tr.outlet_flux(&f));
        }
    }
}
