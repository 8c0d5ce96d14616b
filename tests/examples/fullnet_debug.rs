//! Temporary: finds long plain-to-inverted gaps in a short full-network run.
fn main() {
    let ms: u64 = std::env::args().nth(1).unwrap().parse().unwrap();
    let report = system_tests::fullnet::network::run(shared::Duration::from_millis(ms), 1, true).unwrap();
    let trace = report.trace.unwrap();
    let mut last_plain = std::collections::HashMap::new();
    let mut shown = 0;
    for (i, (at, frame, _)) in trace.iter().enumerate() {
        let id = frame.id().raw();
        if !(0x101..=0x180).contains(&id) { continue; }
        if id % 2 == 1 { last_plain.insert(id, (i, *at)); }
        else if let Some((j, p)) = last_plain.remove(&(id - 1)) {
            if at.as_micros() - p.as_micros() > 5000 && shown < 2 {
                shown += 1;
                println!("gap {} µs on {:03X}", at.as_micros() - p.as_micros(), id);
                for (at, frame, from) in &trace[j.saturating_sub(3)..=i] {
                    let fid = frame.id().raw();
                    if fid == id || fid == id - 1 || !(0x101..=0x180).contains(&fid) {
                        println!("{:>10} {:03X} {:02X?} from {}", at.as_micros(), fid, frame.data(), from);
                    }
                }
            }
        }
    }
}
