//! Commit: an albedo painting taken into the scene as yarn colour orders, where it is one.
//!
//! A painting gives every [cell](super::cells) (one crossing-long section of one thread) its
//! own colour; a colourway (`[materials.palette]` with `warp_order` and `weft_order`, see
//! docs/COLOURWAYS.md) gives every thread of the cloth one palette colour, repeating. A
//! painting is a colour order when
//! - every thread inside the swatch is one colour along its whole length;
//! - per direction, the threads' colours repeat: for some `L`, thread `g` has the colour of
//!   every thread `g + kL`, where `g` is the thread's [global index](PaintCells::global_thread)
//!   (the weave column or row it is, which stays put when the exemplar's repeat grows). `L` is
//!   at most the number of threads inside the swatch (every thread of the order is then one
//!   the designer painted), and its joint repeat with the weave ([`exemplar_repeat`]) at most
//!   [`MAX_REPEAT_THREADS`]; the smallest such `L` is taken;
//! - the distinct yarn colours fit a palette ([`MAX_PALETTE_COLOURS`]).
//!
//! [`commit_colour_orders`] then writes the palette and the orders into a copy of the scene.
//! A thread's palette colour is its yarn as the scene had it, recoloured: the entry the old
//! colour order gave that thread (keeping the entry's base yarn and C_R) or, without a
//! colourway, the warp or weft yarn itself; with the painted colour as its C_TT (fiber yarns)
//! or albedo (Lambert yarns). Equal recolourings share one entry, named `paint01`, `paint02`,
//! ... in the order the warp and then the weft order first use them (zero-padded, so the
//! palette's alphabetical order is that order). Each order starts at global index 0, so that
//! order thread `g mod L` is thread `g`'s.
//!
//! Colours compare as a paint file stores them (f32, bit for bit) and are written as those
//! f32 values (each channel as the shortest decimal that reads back as that f32), except that
//! a colour equal at f32 to the thread's own keeps the scene's exact value: an unpainted scene
//! commits to the very materials it had.
//!
//! The exemplar copies just beyond the swatch's edges have threads with cells too (a painting
//! reaches them only through `base`, `all` or `random`); they take the orders' colours, and
//! [`CommittedOrders::edge_threads_changed`] counts those whose painted colour that changes.

use super::cells::PaintCells;
use crate::Rgb;
use crate::bcsdf::MaterialDesc;
use crate::fabric::colour_order::{MAX_REPEAT_THREADS, exemplar_repeat};
use crate::scene::{MAX_PALETTE_COLOURS, PaletteColour, SceneFile, YarnSlot};

/// One direction's colour order as committed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommittedOrder {
    /// Threads in the colour repeat.
    pub threads: usize,
    /// Palette colours the order uses.
    pub colours: usize,
    /// Threads beyond the swatch's edges whose painted colour the order changes (somewhere
    /// along them).
    pub edge_threads_changed: usize,
}

/// A painting committed as the scene's colourway (how: the `paint::commit` module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct CommittedOrders {
    /// The scene with the new `[materials]`: the palette, both orders, and the warp and weft
    /// yarn materials the palette recolours written out.
    pub scene: SceneFile,
    pub warp: CommittedOrder,
    pub weft: CommittedOrder,
    /// Threads beyond the swatch's edges, both directions, whose painted colour the orders
    /// change.
    pub edge_threads_changed: usize,
    /// One line: `"warp: 4 colours over 6 threads; weft: 1 colour"`.
    pub summary: String,
}

impl CommittedOrders {
    /// What the orders change beyond the painting, if anything: the edge threads they
    /// recolour.
    #[must_use]
    pub fn edge_note(&self) -> Option<String> {
        let counts = [
            (self.warp.edge_threads_changed, "warp end", "warp ends"),
            (self.weft.edge_threads_changed, "weft pick", "weft picks"),
        ];
        let parts: Vec<String> =
            counts.iter().filter(|c| c.0 > 0).map(|&(count, one, many)| plural(count, one, many)).collect();
        (!parts.is_empty()).then(|| {
            format!(
                "{} just beyond the swatch's edges (which a painting reaches only through `base`, `all` \
                 or `random`) take the colour orders' colours instead of their painted ones",
                parts.join(" and ")
            )
        })
    }
}

/// `"warp: 4 colours over 6 threads; weft: 1 colour"`.
fn summary(warp: &CommittedOrder, weft: &CommittedOrder) -> String {
    let describe = |order: &CommittedOrder| {
        let colours = plural(order.colours, "colour", "colours");
        if order.threads == 1 { colours } else { format!("{colours} over {} threads", order.threads) }
    };
    format!("warp: {}; weft: {}", describe(warp), describe(weft))
}

/// Why a painting is not a colour order (or cannot be committed to this scene).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NotAColourOrder {
    #[error("{count} colours for {cells} paint cells: give one colour per cell")]
    ColourCount { count: usize, cells: usize },
    #[error("{reason}")]
    NotWoven { reason: String },
    #[error(
        "the paint cells are not this scene's: they hold {cells} {threads} per exemplar copy, and \
         the scene's exemplar repeat has {expected}"
    )]
    OtherScene { threads: &'static str, cells: u32, expected: usize },
    #[error("[materials]: {message}")]
    Colourway { message: String },
    #[error(
        "the swatch holds no {threads} whose centre lies inside it: there is nothing to take a \
         colour order from"
    )]
    NoThreads { threads: &'static str },
    #[error(
        "{thread} has {colours} colours along it (sections {runs}); a colour order colours whole \
         threads: paint it one colour along its length, or keep the painting as a painting"
    )]
    ThreadInSections { thread: String, colours: usize, runs: String },
    #[error(
        "the painted {threads} do not repeat within {MAX_REPEAT_THREADS} threads ({first} and {second}, \
         {MAX_REPEAT_THREADS} apart, differ, and every shorter repeat breaks too); a colour order \
         repeats within {MAX_REPEAT_THREADS}"
    )]
    NotPeriodic { threads: &'static str, first: String, second: String },
    #[error(
        "the painted {threads} repeat every {period} threads at the shortest ({inside} lie inside \
         the swatch), and with the weave's repeat of {weave} a colour order of {period} threads \
         repeats every {joint}; a colour order repeats within {MAX_REPEAT_THREADS}, so none gives \
         this painting"
    )]
    RepeatTooLong { threads: &'static str, period: usize, inside: u32, weave: usize, joint: usize },
    #[error(
        "the committed palette would hold {count} colours ({warp} in the warp order, {weft} in the \
         weft order: one per yarn and painted colour); a palette holds at most {MAX_PALETTE_COLOURS}"
    )]
    TooManyColours { count: usize, warp: usize, weft: usize },
}

/// A colour as a paint file stores it: each channel's f32, by its bits.
type StoredColour = [u32; 3];

fn stored(c: Rgb) -> StoredColour {
    [c.x, c.y, c.z].map(|v| (v as f32).to_bits())
}

/// A stored colour as the scene file writes it: per channel the shortest decimal that reads
/// back as the same f32 (`0.9`, not `0.8999999761581421`; the same colour to a paint file).
fn written(c: StoredColour) -> Rgb {
    Rgb::from_array(c.map(|bits| {
        f32::from_bits(bits).to_string().parse().expect("a float prints as a number that parses")
    }))
}

/// The colour a painting paints on a yarn of this material (C_TT, or a Lambert albedo).
fn paint_colour(material: &MaterialDesc) -> Rgb {
    match material {
        MaterialDesc::Fiber(p) => p.c_tt,
        MaterialDesc::Lambert { albedo } => *albedo,
    }
}

/// A thread's yarn in the committed palette: the yarn material it recolours, the C_R it
/// keeps, and its painted colour.
#[derive(Debug, Clone, Copy)]
struct YarnColour {
    base: YarnSlot,
    c_r: Option<Rgb>,
    colour: StoredColour,
    /// What to write: the thread's own exact colour where it rounds to `colour`.
    exact: Rgb,
}

impl YarnColour {
    /// Whether two threads take the same palette entry.
    fn same_entry(&self, other: &Self) -> bool {
        (self.base, self.c_r, self.colour) == (other.base, other.c_r, other.colour)
    }
}

/// A thread's yarn as the scene has it: the palette entry's base and C_R, and its material.
struct OldYarn {
    base: YarnSlot,
    c_r: Option<Rgb>,
    material: MaterialDesc,
}

fn thread_name(warp: bool, thread: i64) -> String {
    format!("{} {thread}", if warp { "warp end" } else { "weft pick" })
}

fn threads_name(warp: bool) -> &'static str {
    if warp { "warp ends" } else { "weft picks" }
}

fn plural(count: usize, one: &str, many: &str) -> String {
    format!("{count} {}", if count == 1 { one } else { many })
}

/// `"0-20 and 21-57"`: runs of sections, at most a few named.
fn describe_runs(runs: &[(u32, u32)]) -> String {
    const NAMED: usize = 4;
    let span = |&(first, last): &(u32, u32)| {
        if first == last { first.to_string() } else { format!("{first}-{last}") }
    };
    let spans: Vec<String> = runs.iter().take(NAMED).map(span).collect();
    if runs.len() > NAMED {
        format!("{} and {} more runs", spans.join(", "), runs.len() - NAMED)
    } else {
        let (last, rest) = spans.split_last().expect("a thread has sections");
        if rest.is_empty() { last.clone() } else { format!("{} and {last}", rest.join(", ")) }
    }
}

/// Commits `colours` (one per cell of `cells`, which must be the scene's: the paint cells of
/// `scene` built) as `scene`'s colourway, where the painting is a colour order: every thread
/// inside the swatch one colour, the colours repeating per direction within the threads inside
/// and within the joint repeat with the weave, at most [`MAX_PALETTE_COLOURS`] yarn colours.
/// The palette names are `paint01`, `paint02`, ...; each order starts at the weave's column
/// (row) 0 (the `paint::commit` module docs say how).
///
/// # Errors
/// A painting that is not a colour order (a thread in sections, no repeat within the limits,
/// too many colours; each names the thread or the numbers), a scene that takes no colour
/// orders (imported fibers, `[pattern]`), cells that are not the scene's, or a colourway the
/// scene's `[materials]` already gets wrong.
pub fn commit_colour_orders(
    scene: &SceneFile,
    cells: &PaintCells,
    colours: &[Rgb],
) -> Result<CommittedOrders, NotAColourOrder> {
    if colours.len() != cells.count() {
        return Err(NotAColourOrder::ColourCount { count: colours.len(), cells: cells.count() });
    }
    if scene.pattern.is_some() {
        let reason = "a painting is of cloth without [pattern] (paint mode draws no patterned cloth), \
                      so it does not become this scene's colour orders";
        return Err(NotAColourOrder::NotWoven { reason: reason.into() });
    }
    let draft = match scene.colour_order_draft() {
        Ok(Some(draft)) => draft,
        Ok(None) => {
            let reason = "colour orders need a woven [fabric], and the scene names none this build knows";
            return Err(NotAColourOrder::NotWoven { reason: reason.into() });
        }
        Err(reason) => return Err(NotAColourOrder::NotWoven { reason }),
    };
    let on_threads = u64::from(cells.warp.threads) * u64::from(cells.warp.sections)
        + u64::from(cells.weft.threads) * u64::from(cells.weft.sections);
    if cells.count() as u64 != on_threads {
        return Err(NotAColourOrder::NotWoven {
            reason: format!(
                "colour orders need a woven fabric: {} paint cells belong to yarns with no weave role, \
                 which no colour order reaches",
                cells.count() as u64 - on_threads
            ),
        });
    }
    let colourway = scene.colourway().map_err(|message| NotAColourOrder::Colourway { message })?;
    let materials =
        scene.material_descs().map_err(|e| NotAColourOrder::Colourway { message: e.to_string() })?;
    for (warp, weave) in [(true, draft.cols()), (false, draft.rows())] {
        let set = if warp { &cells.warp } else { &cells.weft };
        let expected = match &colourway {
            Some(c) => {
                let (what, order) = if warp { ("warp_order", &c.warp) } else { ("weft_order", &c.weft) };
                exemplar_repeat(what, weave, order.threads().len())
                    .map_err(|e| NotAColourOrder::Colourway { message: e.to_string() })?
            }
            None => weave,
        };
        if set.per_period as usize != expected {
            return Err(NotAColourOrder::OtherScene {
                threads: threads_name(warp),
                cells: set.per_period,
                expected,
            });
        }
    }
    let old_yarn = |warp: bool, g: i64| -> OldYarn {
        let slot = if warp { YarnSlot::Warp } else { YarnSlot::Weft };
        match &colourway {
            Some(c) => {
                let order = if warp { c.warp.threads() } else { c.weft.threads() };
                let k = order[g.rem_euclid(order.len() as i64) as usize] as usize;
                let entry = &scene.materials.palette[&c.names[k]];
                OldYarn { base: entry.base, c_r: entry.c_r, material: c.materials[k] }
            }
            None => OldYarn { base: slot, c_r: None, material: materials[slot as usize] },
        }
    };

    let warp = painted_threads(true, cells, colours, &old_yarn)?;
    let weft = painted_threads(false, cells, colours, &old_yarn)?;
    let warp_period = shortest_period(true, &warp, draft.cols())?;
    let weft_period = shortest_period(false, &weft, draft.rows())?;

    // The palette, in the order the warp and then the weft order first use its entries.
    let mut entries: Vec<YarnColour> = Vec::new();
    let mut order_of = |warp: bool, threads: &[YarnColour], period: usize| -> Vec<usize> {
        let g0 = cells.global_thread(warp, 0);
        (0..period as i64)
            .map(|k| {
                let thread = &threads[(k - g0).rem_euclid(period as i64) as usize];
                entries.iter().position(|e| e.same_entry(thread)).unwrap_or_else(|| {
                    entries.push(*thread);
                    entries.len() - 1
                })
            })
            .collect()
    };
    let warp_order = order_of(true, &warp, warp_period);
    let weft_order = order_of(false, &weft, weft_period);
    let used = |order: &[usize]| {
        let mut distinct = order.to_vec();
        distinct.sort_unstable();
        distinct.dedup();
        distinct.len()
    };
    let (warp_colours, weft_colours) = (used(&warp_order), used(&weft_order));
    if entries.len() > MAX_PALETTE_COLOURS {
        return Err(NotAColourOrder::TooManyColours {
            count: entries.len(),
            warp: warp_colours,
            weft: weft_colours,
        });
    }

    let names: Vec<String> = (1..=entries.len()).map(|k| format!("paint{k:02}")).collect();
    let slots = scene.material_slots();
    let palette = entries
        .iter()
        .zip(&names)
        .map(|(entry, name)| {
            // As `colourway` resolves it: a slot nothing gives is a Lambert yarn.
            let lambert = !matches!(slots[entry.base as usize], Some(MaterialDesc::Fiber(_)));
            let colour = PaletteColour {
                base: entry.base,
                c_r: if lambert { None } else { entry.c_r },
                c_tt: (!lambert).then_some(entry.exact),
                albedo: lambert.then_some(entry.exact),
            };
            (name.clone(), colour)
        })
        .collect();
    let runs = |order: &[usize]| {
        order
            .chunk_by(|a, b| a == b)
            .map(|run| format!("{} {}", run.len(), names[run[0]]))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut committed = scene.clone();
    let m = &mut committed.materials;
    [m.warp, m.weft] = slots;
    m.warp_order = Some(runs(&warp_order));
    m.weft_order = Some(runs(&weft_order));
    m.palette = palette;
    committed.check_colourway().map_err(|message| NotAColourOrder::Colourway { message })?;

    let edge = |warp: bool, order: &[usize]| {
        recoloured_edge_threads(warp, cells, colours, |g| {
            entries[order[g.rem_euclid(order.len() as i64) as usize]].colour
        })
    };
    let warp = CommittedOrder {
        threads: warp_period,
        colours: warp_colours,
        edge_threads_changed: edge(true, &warp_order),
    };
    let weft = CommittedOrder {
        threads: weft_period,
        colours: weft_colours,
        edge_threads_changed: edge(false, &weft_order),
    };
    Ok(CommittedOrders {
        scene: committed,
        edge_threads_changed: warp.edge_threads_changed + weft.edge_threads_changed,
        summary: summary(&warp, &weft),
        warp,
        weft,
    })
}

/// The yarn colour of each thread inside the swatch (by its painting number), each checked
/// to be one colour along its length.
fn painted_threads(
    warp: bool,
    cells: &PaintCells,
    colours: &[Rgb],
    old_yarn: &impl Fn(bool, i64) -> OldYarn,
) -> Result<Vec<YarnColour>, NotAColourOrder> {
    let set = if warp { &cells.warp } else { &cells.weft };
    if set.inside == 0 {
        return Err(NotAColourOrder::NoThreads { threads: threads_name(warp) });
    }
    let mut threads = Vec::with_capacity(set.inside as usize);
    for thread in 0..i64::from(set.inside) {
        let along: Vec<StoredColour> = cells
            .thread_cells(warp, thread, 0..set.sections)
            .expect("a thread inside the swatch has cells")
            .iter()
            .map(|&c| stored(colours[c as usize]))
            .collect();
        let mut runs = Vec::new();
        let mut first = 0_u32;
        for run in along.chunk_by(|a, b| a == b) {
            let last = first + run.len() as u32 - 1;
            runs.push((first, last));
            first = last + 1;
        }
        if runs.len() > 1 {
            let mut distinct = along.clone();
            distinct.sort_unstable();
            distinct.dedup();
            return Err(NotAColourOrder::ThreadInSections {
                thread: thread_name(warp, thread),
                colours: distinct.len(),
                runs: describe_runs(&runs),
            });
        }
        let old = old_yarn(warp, cells.global_thread(warp, thread));
        let own = paint_colour(&old.material);
        let colour = along[0];
        let exact = if stored(own) == colour { own } else { written(colour) };
        threads.push(YarnColour { base: old.base, c_r: old.c_r, colour, exact });
    }
    Ok(threads)
}

/// The smallest colour repeat `L` (at most the inside threads and [`MAX_REPEAT_THREADS`])
/// over which the threads' yarn colours repeat and which fits the weave's repeat `weave`.
fn shortest_period(warp: bool, threads: &[YarnColour], weave: usize) -> Result<usize, NotAColourOrder> {
    let breaks = |period: usize| {
        (0..threads.len().saturating_sub(period)).find(|&t| !threads[t].same_entry(&threads[t + period]))
    };
    let mut shortest = None;
    for period in 1..=threads.len().min(MAX_REPEAT_THREADS) {
        if breaks(period).is_some() {
            continue;
        }
        let what = if warp { "warp_order" } else { "weft_order" };
        if exemplar_repeat(what, weave, period).is_ok() {
            return Ok(period);
        }
        shortest.get_or_insert(period);
    }
    if let Some(period) = shortest {
        return Err(NotAColourOrder::RepeatTooLong {
            threads: threads_name(warp),
            period,
            inside: threads.len() as u32,
            weave,
            joint: weave / gcd(weave, period) * period,
        });
    }
    // No repeat at all: more threads inside than a repeat holds, and every repeat breaks.
    let t = breaks(MAX_REPEAT_THREADS).expect("every repeat breaks") as i64;
    Err(NotAColourOrder::NotPeriodic {
        threads: threads_name(warp),
        first: thread_name(warp, t),
        second: thread_name(warp, t + MAX_REPEAT_THREADS as i64),
    })
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// Threads beyond the swatch's edges painted, somewhere along them, other than the colour
/// `order_colour(g)` their global index `g` takes.
fn recoloured_edge_threads(
    warp: bool,
    cells: &PaintCells,
    colours: &[Rgb],
    order_colour: impl Fn(i64) -> StoredColour,
) -> usize {
    let set = if warp { &cells.warp } else { &cells.weft };
    let (before, after) = (i64::from(set.first_inside), i64::from(set.threads - set.first_inside));
    (-before..0)
        .chain(i64::from(set.inside)..after)
        .filter(|&thread| {
            let colour = order_colour(cells.global_thread(warp, thread));
            let along = cells.thread_cells(warp, thread, 0..set.sections).expect("the set's own threads");
            along.iter().any(|&c| stored(colours[c as usize]) != colour)
        })
        .count()
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::paint::{Painting, scene_colours};
    use crate::scene::{Colourway, Scene};

    /// The colourway of a scene that has one.
    fn committed_colourway(scene: &SceneFile) -> Colourway {
        scene.colourway().expect("the colourway parses").expect("the scene has one")
    }

    /// The scene built and its paint cells.
    fn built(file: &SceneFile) -> (Scene, PaintCells) {
        let scene = file.build().expect("scene builds");
        let cells = PaintCells::new(&scene.exemplar, &scene.path_scene.fibers).expect("a finite swatch");
        (scene, cells)
    }

    /// The painting `text` resolved on `cells`, over the scene's own colours `own`.
    fn painted(text: &str, cells: &PaintCells, own: &[Rgb]) -> Vec<Rgb> {
        let path = Path::new("commit-test.toml");
        Painting::parse(text, path).unwrap().colours(cells, own, path).unwrap()
    }

    /// `"1, 2, 6, 7, ..."`: the threads of `0..count` at places `at` of every `repeat`.
    fn in_repeat(repeat: u32, at: &[u32], count: u32) -> String {
        let threads = (0..count).filter(|t| at.contains(&(t % repeat)));
        threads.map(|t| t.to_string()).collect::<Vec<_>>().join(", ")
    }

    /// Every inside thread's every section has the same colour (at f32) in both cloths.
    fn assert_same_inside(
        (cells, colours): (&PaintCells, &[Rgb]),
        (new_cells, new_colours): (&PaintCells, &[Rgb]),
    ) {
        for (warp, set, new_set) in
            [(true, &cells.warp, &new_cells.warp), (false, &cells.weft, &new_cells.weft)]
        {
            assert_eq!((set.inside, set.sections), (new_set.inside, new_set.sections), "the same swatch");
            for thread in 0..i64::from(set.inside) {
                assert_eq!(cells.global_thread(warp, thread), new_cells.global_thread(warp, thread));
                let old = cells.thread_cells(warp, thread, 0..set.sections).unwrap();
                let new = new_cells.thread_cells(warp, thread, 0..set.sections).unwrap();
                for (s, (&a, &b)) in old.iter().zip(&new).enumerate() {
                    assert_eq!(
                        stored(colours[a as usize]),
                        stored(new_colours[b as usize]),
                        "{} section {s}",
                        thread_name(warp, thread)
                    );
                }
            }
        }
    }

    #[test]
    fn stripes_commit_and_the_committed_scene_paints_them_again() {
        let file = SceneFile::default_scene();
        let (scene, cells) = built(&file);
        let own = scene_colours(&scene.path_scene, &cells);
        // Warp: ends 1 and 2 of every 5 navy over the base; weft: picks 0-2 of every 8 red.
        // Neither repeat divides the 36 threads from the origin to the first exemplar copy the
        // cells hold (copy -9 of 4), so a thread numbering off by copies would show.
        let text = format!(
            "base = [0.8, 0.75, 0.6]\n[[stroke]]\ncolour = [0.05, 0.1, 0.5]\nwarp = \"{}\"\n\
             [[stroke]]\ncolour = [0.9, 0.2, 0.1]\nweft = \"{}\"\n",
            in_repeat(5, &[1, 2], cells.warp.inside),
            in_repeat(8, &[0, 1, 2], cells.weft.inside)
        );
        let colours = painted(&text, &cells, &own);
        let committed = commit_colour_orders(&file, &cells, &colours).unwrap();
        assert_eq!(committed.summary, "warp: 2 colours over 5 threads; weft: 2 colours over 8 threads");
        let colourway = committed_colourway(&committed.scene);
        assert_eq!(colourway.names, ["paint01", "paint02", "paint03", "paint04"]);
        let written_colours: Vec<_> = committed.scene.materials.palette.values().map(|c| c.c_tt).collect();
        let navy = Some(Rgb::new(0.05, 0.1, 0.5));
        assert!(written_colours.contains(&navy), "as the painting gives it: {written_colours:?}");
        let (new_scene, new_cells) = built(&committed.scene);
        assert_eq!(new_cells.warp.per_period, 20, "the warp repeat grows to lcm(4, 5)");
        let new_colours = scene_colours(&new_scene.path_scene, &new_cells);
        assert_same_inside((&cells, &colours), (&new_cells, &new_colours));
        // The edge threads take the order where the painting left them the base colour.
        let edge = |set: &crate::paint::ThreadSet, repeat: i64, at: &[i64]| {
            let first = -i64::from(set.first_inside);
            (first..0)
                .chain(i64::from(set.inside)..first + i64::from(set.threads))
                .filter(|t| at.contains(&t.rem_euclid(repeat)))
                .count()
        };
        assert_eq!(committed.warp.edge_threads_changed, edge(&cells.warp, 5, &[1, 2]));
        assert_eq!(committed.weft.edge_threads_changed, edge(&cells.weft, 8, &[0, 1, 2]));
        let note = committed.edge_note().expect("edge threads change");
        assert!(note.contains("just beyond the swatch's edges"), "{note}");
    }

    #[test]
    fn colours_are_written_as_the_shortest_decimal_of_their_f32() {
        assert_eq!(written(stored(Rgb::new(0.9, 0.05, 1.0))), Rgb::new(0.9, 0.05, 1.0));
        for k in 0..=1000 {
            let v = f64::from(k) / 1000.0 + 1e-9;
            let c = stored(Rgb::splat(v));
            assert_eq!(stored(written(c)), c, "{v}");
        }
    }

    #[test]
    fn the_unpainted_scene_commits_to_its_own_colours_exactly() {
        let lambert = SceneFile::parse(
            &crate::scene::DEFAULT_SCENE_TOML.replace(
                "[swatch]",
                "[materials]\nwarp = { model = \"lambert\", albedo = [0.3, 0.2, 0.1] }\n[swatch]",
            ),
            Path::new("lambert.toml"),
        )
        .unwrap();
        for file in [SceneFile::default_scene(), lambert] {
            let (scene, cells) = built(&file);
            let own = scene_colours(&scene.path_scene, &cells);
            let committed = commit_colour_orders(&file, &cells, &own).unwrap();
            assert_eq!(committed.summary, "warp: 1 colour; weft: 1 colour");
            assert_eq!(committed.edge_threads_changed, 0);
            assert_eq!(committed.edge_note(), None);
            let m = &committed.scene.materials;
            assert_eq!(
                (m.warp_order.as_deref(), m.weft_order.as_deref()),
                (Some("1 paint01"), Some("1 paint02"))
            );
            assert_eq!(committed.scene.material_descs().unwrap(), file.material_descs().unwrap());
            let (new_scene, new_cells) = built(&committed.scene);
            assert_eq!(new_cells, cells);
            let new_own = scene_colours(&new_scene.path_scene, &new_cells);
            assert!(new_own == own, "{}: the same colours, bit for bit", file.path.display());
        }
    }

    #[test]
    fn what_is_no_colour_order_is_refused_naming_the_thread_or_the_numbers() {
        let file = SceneFile::default_scene();
        let (scene, cells) = built(&file);
        let own = scene_colours(&scene.path_scene, &cells);
        let refused = |colours: &[Rgb]| commit_colour_orders(&file, &cells, colours).unwrap_err().to_string();

        let sections = painted(
            "[[stroke]]\ncolour = [0.9, 0.2, 0.1]\nwarp = \"12\"\nsections = \"0-20\"\n",
            &cells,
            &own,
        );
        let message = refused(&sections);
        let last = cells.warp.sections - 1;
        assert!(
            message.contains(&format!("warp end 12 has 2 colours along it (sections 0-20 and 21-{last})")),
            "{message}"
        );

        // Every warp end its own colour: no repeat short enough. Over the default swatch's 58
        // ends only all 58 repeat; over a 3 cm swatch (85 ends) nothing does.
        let random = |cells: &PaintCells, own: &[Rgb]| {
            let mut colours = own.to_vec();
            for thread in 0..cells.warp.inside {
                let t = f64::from(thread);
                let colour = Rgb::new((t * 0.37).fract(), (t * 0.61).fract(), (t * 0.13).fract());
                for c in cells.thread_cells(true, t as i64, 0..cells.warp.sections).unwrap() {
                    colours[c as usize] = colour;
                }
            }
            colours
        };
        let message = refused(&random(&cells, &own));
        assert!(
            message.contains(&format!("painted warp ends repeat every {} threads", cells.warp.inside))
                && message.contains("weave's repeat of 4")
                && message.contains("within 64"),
            "{message}"
        );
        let wide = SceneFile::parse(
            &crate::scene::DEFAULT_SCENE_TOML.replace("size_cm = [2.0, 2.0]", "size_cm = [3.0, 3.0]"),
            Path::new("wide.toml"),
        )
        .unwrap();
        let (wide_scene, wide_cells) = built(&wide);
        assert!(wide_cells.warp.inside > 64, "{} warp ends", wide_cells.warp.inside);
        let colours = random(&wide_cells, &scene_colours(&wide_scene.path_scene, &wide_cells));
        let message = commit_colour_orders(&wide, &wide_cells, &colours).unwrap_err().to_string();
        assert!(
            message.contains("painted warp ends do not repeat within 64 threads (warp end 0 and warp end 64"),
            "{message}"
        );

        // Sixteen warp colours in a repeat of 16 and the weft's own: 17 palette colours.
        let mut many = own.clone();
        for thread in 0..cells.warp.inside {
            let level = f64::from(thread % 16) / 16.0;
            for c in cells.thread_cells(true, i64::from(thread), 0..cells.warp.sections).unwrap() {
                many[c as usize] = Rgb::new(level, 0.5, 0.5);
            }
        }
        let message = refused(&many);
        assert!(message.contains("17 colours (16 in the warp order, 1 in the weft order"), "{message}");
        assert!(message.contains("at most 16"), "{message}");

        let patterned = SceneFile::parse(
            &crate::scene::DEFAULT_SCENE_TOML.replace(
                "[swatch]",
                "[pattern]\nweaves = [{ weave = \"plain\" }]\nrows = [\"01\"]\n[swatch]",
            ),
            Path::new("patterned.toml"),
        )
        .unwrap();
        let message = commit_colour_orders(&patterned, &cells, &own).unwrap_err().to_string();
        assert!(message.contains("a painting is of cloth without [pattern]"), "{message}");
        let message = commit_colour_orders(&file, &cells, &own[1..]).unwrap_err().to_string();
        assert!(message.contains("give one colour per cell"), "{message}");
    }

    #[test]
    fn a_colourway_keeps_each_threads_entry_and_its_c_r() {
        let file = SceneFile::parse(
            &crate::scene::DEFAULT_SCENE_TOML.replace(
                "[swatch]",
                "[materials]\nwarp_order = \"1 navy, 1 cream\"\nweft_order = \"1 cream\"\n\
                 [materials.palette]\nnavy = { base = \"warp\", c_r = [0.1, 0.1, 0.12], c_tt = [0.05, 0.07, 0.3] }\n\
                 cream = { base = \"weft\" }\n[swatch]",
            ),
            Path::new("colourway.toml"),
        )
        .unwrap();
        let (scene, cells) = built(&file);
        let own = scene_colours(&scene.path_scene, &cells);
        // All warp ends one colour: the navy and cream ends still differ in C_R and base yarn.
        let all_warp =
            format!("[[stroke]]\ncolour = [0.6, 0.3, 0.2]\nwarp = \"0-{}\"\n", cells.warp.inside - 1);
        let colours = painted(&all_warp, &cells, &own);
        let committed = commit_colour_orders(&file, &cells, &colours).unwrap();
        assert_eq!(committed.summary, "warp: 2 colours over 2 threads; weft: 1 colour");
        let new = committed_colourway(&committed.scene);
        let old = committed_colourway(&file);
        let palette = &committed.scene.materials.palette;
        for thread in 0..i64::from(cells.warp.inside) {
            let g = cells.global_thread(true, thread) as usize;
            let (was, is) = (
                &file.materials.palette[&old.names[old.warp.colour_of(g) as usize]],
                &palette[&new.names[new.warp.colour_of(g) as usize]],
            );
            assert_eq!((is.base, is.c_r), (was.base, was.c_r), "warp end {thread}");
            assert_eq!(is.c_tt.map(stored), Some(stored(Rgb::new(0.6, 0.3, 0.2))), "warp end {thread}");
        }
        let (new_scene, new_cells) = built(&committed.scene);
        assert_same_inside(
            (&cells, &colours),
            (&new_cells, &scene_colours(&new_scene.path_scene, &new_cells)),
        );
    }
}
