//! `sweepdepth eval` (placeholder).

#[derive(Debug, clap::Args)]
pub struct EvalArgs {}

pub fn run(_args: &EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("eval is not implemented yet")
}
