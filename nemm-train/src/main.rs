//! `nemm`: the command-line interface of nemm-train.
fn main() {
    eprintln!("nemm: the trainer is not built yet; see README.md");
    std::process::exit(2);
}
