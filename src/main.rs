fn main() {
    println!("lipcall");
}
