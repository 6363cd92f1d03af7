//! Embeds the crate's `migrations/*.sql` (`NNNN_description.sql`) in the
//! library as `$OUT_DIR/migrations.rs`: a list of (version, description,
//! SQL) that `springbench_store::migrations::migrator` turns into sqlx's
//! `Migrator`. It replaces `sqlx::migrate!`, whose proc-macro crate built a
//! second copy of sqlx, both database drivers and SQLite's C source for the
//! host (decision 0042). springbench-store-pg uses this same script.

use std::path::Path;
use std::{env, fs};

fn main() {
    let dir = Path::new(&env::var("CARGO_MANIFEST_DIR").unwrap()).join("migrations");
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut files: Vec<_> = fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("reading {}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "sql"))
        .collect();
    files.sort();
    let mut out = String::from("&[\n");
    for p in &files {
        let name = p.file_name().unwrap().to_str().expect("UTF-8 file name");
        let (version, rest) = name
            .split_once('_')
            .unwrap_or_else(|| panic!("migration {name}: expected NNNN_description.sql"));
        let version: i64 = version
            .parse()
            .unwrap_or_else(|_| panic!("migration {name}: the version {version:?} is no integer"));
        let description = rest.trim_end_matches(".sql").replace('_', " ");
        out.push_str(&format!(
            "    ({version}, {description:?}, include_str!({:?})),\n",
            p.display().to_string()
        ));
    }
    out.push(']');
    let dest = Path::new(&env::var("OUT_DIR").unwrap()).join("migrations.rs");
    fs::write(dest, out).unwrap();
}
