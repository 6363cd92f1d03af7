//! `springbench devices`: the audio devices (channels, formats, rates) and the
//! serial ports this machine offers, to fill in `[benches.hardware]`.

#[derive(clap::Args, Debug, Default, Clone)]
pub struct DevicesArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

#[cfg(feature = "hardware")]
pub fn run(a: DevicesArgs) -> Result<(), String> {
    let audio = crate::bench::hardware::cpal_io::list_devices()
        .map_err(|e| format!("audio devices: {e}"))?;
    let serial: Vec<(String, String)> = tokio_serial::available_ports()
        .map(|ps| {
            ps.into_iter()
                .map(|p| (p.port_name, format!("{:?}", p.port_type)))
                .collect()
        })
        .unwrap_or_default();
    if a.json {
        let v = serde_json::json!({
            "audio": audio,
            "serial": serial.iter().map(|(n, t)| serde_json::json!({"port": n, "type": t})).collect::<Vec<_>>(),
        });
        println!("{v:#}");
        return Ok(());
    }
    println!("audio devices (use the name after 'alsa:' as output_device / input_device):");
    for d in &audio {
        println!("  {}  ({})", d.id, d.name);
        for i in &d.inputs {
            println!("      in  {i}");
        }
        for o in &d.outputs {
            println!("      out {o}");
        }
    }
    println!("serial ports:");
    if serial.is_empty() {
        println!("  (none found)");
    }
    for (n, t) in &serial {
        println!("  {n}  {t}");
    }
    Ok(())
}

#[cfg(not(feature = "hardware"))]
pub fn run(_a: DevicesArgs) -> Result<(), String> {
    Err("this springbench was built without the `hardware` feature (cargo build --features hardware)".into())
}
