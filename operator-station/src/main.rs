//! `operator-station`: the terranav operator station (see `operator-station --help`).

fn main() -> anyhow::Result<()> {
    operator_station::cli::main()
}
