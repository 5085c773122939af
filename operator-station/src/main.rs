//! `operator-station`: the terranav operator station.

fn main() {
    eprintln!("operator-station: not built yet");
    std::process::exit(2);
}
