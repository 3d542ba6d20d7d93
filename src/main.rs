//! The `bake` binary: the command line of the library ([`bake::cli::main`]: parses arguments,
//! calls the library, prints, maps errors to exit codes).

fn main() {
    bake::cli::main();
}
