//! `springbench openapi`: prints the API's OpenAPI document (generated from
//! the code, `api::openapi`): YAML as in `api/openapi.yaml`, or `--json` as
//! `GET /api/openapi.json` serves it.

#[derive(clap::Args, Debug, Default)]
pub struct OpenapiArgs {
    /// Print JSON instead of YAML.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: OpenapiArgs) -> Result<(), String> {
    use std::io::Write;
    let text = if a.json {
        format!("{}\n", crate::api::openapi::json())
    } else {
        crate::api::openapi::yaml()
    };
    std::io::stdout()
        .write_all(text.as_bytes())
        .map_err(|e| format!("stdout: {e}"))
}
