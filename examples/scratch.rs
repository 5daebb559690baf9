use plumenet::layout::Layout;
use plumenet::physics::{wind::WindField, transport::Transport, filament::{FilamentPlume, FilamentConfig}};
use std::time::Instant;
fn main() {
    let e = Layout::from_json(r#"{"width_m":18,"height_m":4,"cell_m":0.125,"wind":{"speed_mps":0.75}}"#).unwrap();
    let w = WindField::solve(&e).unwrap();
    let tr = Transport::new(&e, &w).unwrap();
    let src = (3.0, 2.0);
    let mean = tr.solve(src.0, src.1).unwrap();
    let mut pl = FilamentPlume::new(&e, &w, src, FilamentConfig::default(), 7).unwrap();
    pl.advance(40.0);
    let pts = [(5.0, 2.0), (8.0, 2.0), (8.0, 2.6), (12.0, 2.0), (12.0, 1.0), (16.0, 2.0), (6.0, 1.5)];
    let mut sums = vec![0.0; pts.len()];
    let mut zeros = vec![0usize; pts.len()];
    let t = Instant::now();
    let n = 20000;
    let mut series = vec![];
    for _ in 0..n {
        pl.step();
        for (k, &(x, y)) in pts.iter().enumerate() {
            let c = pl.concentration_at(x, y);
            sums[k] += c;
            if k == 1 { series.push(c); }
        }
    }
    println!("time {:?} filaments {}", t.elapsed(), pl.len());
    for (k, &(x, y)) in pts.iter().enumerate() {
        let (j, i) = e.cell_of(x, y);
        let m = mean[[j, i]];
        let avg = sums[k] / n as f64;
        println!("({x},{y}) mean {m:.4} avg {avg:.4} rel {:.3}", avg / m - 1.0);
    }
    let avg = series.iter().sum::<f64>() / n as f64;
    let sd = (series.iter().map(|c| (c - avg).powi(2)).sum::<f64>() / n as f64).sqrt();
    let low = series.iter().filter(|&&c| c < 0.1 * avg).count() as f64 / n as f64;
    println!("cv {:.3} frac<0.1mean {:.3}", sd / avg, low);
    let _ = zeros.iter_mut();
}
