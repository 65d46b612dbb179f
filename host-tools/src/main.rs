fn main() {
    println!("slipguard: see `slipguard --help`");
}
